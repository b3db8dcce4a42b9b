"""``btel extract``: describe a folder of images into one descriptor matrix (cached beside it)."""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import click

from ._errors import InputError
from ._outputs import check_output_suffix, refuse_existing
from ._params import ParamCommand, _param_value

#: What --param can set, per descriptor (tests/test_cli_extract.py checks it against get_params()); the
#: methods' list (`btel methods --params`) does not hold descriptors, and --help must not import them.
_DESCRIPTOR_PARAMS_HELP = ("hog: orientations, pixels_per_cell, cells_per_block, block_norm; patchnorm: patch_size; "
                           "densevlad: n_clusters, n_components, step, sizes, max_side, max_descriptors, kmeans_iter, "
                           "random_state (size: use --size). VALUE is read as JSON when it is a JSON literal (3, "
                           "[4, 4], true), else kept as text (L2-Hys). A bad name lists the descriptor's parameters.")


@click.command(cls=ParamCommand)
@click.argument("images_dir", type=click.Path(file_okay=False))
@click.option("-o", "--output", "--out", "output", required=True, type=click.Path(dir_okay=False),
              help="Descriptor matrix to write (.npy).")
@click.option("--descriptor", default="hog", show_default=True,
              help="hog | patchnorm | densevlad, or a descriptor file saved with --save-descriptor.")
@click.option("--size", default=None, metavar="WxH",
              help="hog / patchnorm: the thumbnail every image is resized to, whatever its aspect (default 64x32, "
                   "Nordland's; a Warning says when it stretches the images, e.g. use 56x32 for 16:9 frames).")
@click.option("--param", "param_texts", multiple=True, metavar="NAME=VALUE",
              help="A parameter of the descriptor, e.g. --param n_components=256 or --param n_clusters=64 "
                   "(densevlad: PCA to n_components, capped at the number of map images − 1, with a Warning). "
                   "Parameters: " + _DESCRIPTOR_PARAMS_HELP)
@click.option("--fit-on", type=click.Path(file_okay=False), default=None,
              help="Map image folder to learn from (DenseVLAD vocabulary + PCA). Never the queries.")
@click.option("--save-descriptor", type=click.Path(dir_okay=False), default=None,
              help="Write the fitted descriptor (e.g. the DenseVLAD vocabulary) to describe the queries with it.")
@click.option("--force", is_flag=True, help="Recompute even if OUTPUT is up to date.")
@click.option("--overwrite", is_flag=True,
              help="Replace an existing OUTPUT (or --save-descriptor file) that holds other descriptors (other "
                   "images, descriptor or parameters). An up-to-date OUTPUT is reused without it.")
@click.option("--delta", "delta", type=int, default=None, metavar="W",
              help="Write delta descriptors of the traverse instead: row j = mean of frames j−W+1…j minus the mean "
                   "of the W before (causal; the first frames count the first image as earlier ones). Needs at "
                   "least 2W images. (Or keep plain descriptors and give --delta W to train/evaluate: the same "
                   "transform as every method's front end, with L2 normalisation around it.)")
@click.option("--no-progress", is_flag=True, help="No progress bar.")
def extract(images_dir: str, output: str, descriptor: str, size: str | None, param_texts: tuple[str, ...],
            fit_on: str | None, save_descriptor: str | None, force: bool, overwrite: bool, delta: int | None,
            no_progress: bool) -> None:
    """Describe every image in IMAGES_DIR (natural file-name order = route order) into one .npy matrix.

    Row i of OUTPUT is the i-th image. A JSON file beside OUTPUT records the descriptor and the
    images; when nothing changed, the existing OUTPUT is reused (a cache) unless --force.

    \b
    What each descriptor does to the images (each prints a Warning when it happens):
      hog, patchnorm  resize every image to --size (64x32); other aspects are stretched.
      densevlad       PCA-whitens to n_components (4096), capped at (map images − 1).
    Images of mixed sizes are described as they are, with a Warning.
    """
    from ..datasets.vpr_names import split_dataset_folder
    from ..descriptors import get_descriptor
    from ..descriptors.base import load_descriptor
    from ..core.storage import format_bytes
    from ..descriptors.extract import extract_cached, extract_delta_cached, extraction_difference, is_extraction_of
    from ..descriptors.images import IMAGE_EXTENSIONS, not_images

    if split_dataset_folder(images_dir) is not None:
        root = Path(images_dir)
        raise click.UsageError(
            f"{images_dir} is a VPR-methods-evaluation data set (database/ and queries/): describe each folder, "
            f"`btel extract {root / 'database'} -o db.npy --save-descriptor d.npz` then `btel extract "
            f"{root / 'queries'} -o q.npy --descriptor d.npz`, and evaluate with --ground-truth utm.")

    check_output_suffix(output, "-o", "a descriptor matrix", (".npy",))
    skipped = not_images(images_dir) if Path(images_dir).is_dir() else []
    if skipped:  # only the images directly inside are read: say what else is there rather than pass it over
        many = len(skipped) != 1
        click.echo(f"Warning: {len(skipped)} entr{'ies' if many else 'y'} of {images_dir} "
                   f"{'are not images' if many else 'is not an image'} btel reads ({', '.join(skipped[:5])}"
                   f"{', …' if len(skipped) > 5 else ''}); images are regular files ending in {', '.join(IMAGE_EXTENSIONS)}.",
                   err=True)
    params: dict[str, Any] = {}
    for text in param_texts:
        name, eq, raw = text.partition("=")
        if not eq or not name.strip().isidentifier():
            raise click.UsageError(f"--param {text!r} is not NAME=VALUE, e.g. n_components=256.")
        params[name.strip()] = _param_value(raw)
    if size is not None:
        match = re.fullmatch(r"\s*(\d+)\s*[xX×]\s*(\d+)\s*", size)
        if not match:
            raise click.UsageError(f"--size {size!r} is not WIDTHxHEIGHT, e.g. 64x32.")
        params["size"] = (int(match.group(1)), int(match.group(2)))
    if not Path(descriptor).is_file() and (Path(descriptor).suffix.lower() == ".npz" or "/" in descriptor):
        raise click.UsageError(f"--descriptor {descriptor}: no such file. Give a saved descriptor file (written by "
                               "--save-descriptor) or a descriptor name (hog, patchnorm, densevlad).")
    if Path(descriptor).is_file():
        if params:
            raise click.UsageError("--size and --param set a new descriptor; a saved descriptor file keeps its own.")
        model = load_descriptor(descriptor)
    else:
        model = get_descriptor(descriptor, **params)
        if "size" in params and "size" not in model.get_params():
            raise click.UsageError(f"--size applies to hog and patchnorm; {descriptor} keeps each image's size.")
    if save_descriptor:
        refuse_existing(save_descriptor, "--save-descriptor", overwrite)
    if delta is not None:
        refuse_existing(output, "-o", overwrite)
        D, X, plain = extract_delta_cached(images_dir, output, model, delta, fit_on=fit_on, progress=not no_progress,
                                           force=force, overwrite=overwrite)
        click.echo(f"{X.shape[0]} images → {D.shape[1]}-D delta descriptors (W = {delta}) of "
                   f"{type(model).__name__} written to {output} (plain descriptors kept in {plain})")
        return
    cache = Path(output).exists() and is_extraction_of(output, images_dir, model, fit_on)
    if Path(output).exists() and not overwrite and not cache:
        changed = extraction_difference(output, images_dir, model, fit_on)
        if changed:  # btel's own earlier extraction of this folder: say what moved since, not just "exists"
            raise InputError(f"-o {output} holds an earlier extraction of these images that no longer matches "
                             f"({changed}); give --overwrite to extract again and replace it, or another -o.")
        refuse_existing(output, "-o", overwrite)
    # A new OUTPUT is published only if still absent (a racing extract's is kept); a cache of the same
    # extraction, or any file with --overwrite, is replaced.
    X, reused = extract_cached(images_dir, output, model, fit_on=fit_on, progress=not no_progress,
                               force=force, overwrite=overwrite or cache)
    if reused:
        click.echo(f"{output} is up to date ({X.shape[0]} images, {descriptor}); use --force to recompute")
        return
    resize = getattr(model, "thumbnail_size", None)
    how = f" (every image resized to {resize[0]}×{resize[1]})" if resize else ""
    click.echo(f"{X.shape[0]} images → {X.shape[1]}-D {type(model).__name__} descriptors{how} written to {output}")
    if save_descriptor:
        path = model.save(save_descriptor, overwrite=overwrite)
        parts = ", ".join(f"{k} {format_bytes(v.nbytes)}" for k, v in model._stored_arrays().items())
        click.echo(f"fitted descriptor written to {path} ({format_bytes(path.stat().st_size)}"
                   f"{': ' + parts if parts else ''})")
