"""The ``btel`` command line: from descriptors (or images) to a model, predictions and a recall report.

Every subcommand has ``--help``. Failures print one line ``Error: …`` on stderr and exit with a
non-zero code (1 for bad data or models, 2 for bad usage, 3 when ``evaluate``/``demo`` finished
but some method did not fit or failed: its row says why); no traceback unless ``BTEL_DEBUG=1``.
Warnings (a distorting resize, a capped PCA) print one line ``Warning: …`` on stderr.

Any parameter of any method is set with ``--param NAME=VALUE`` (``train``, ``evaluate``, ``demo``);
the named BTEL options of ``train`` are shortcuts that fill the same parameters. Names are checked
against the method's ``get_params()`` before anything is fitted.
"""

from __future__ import annotations

import csv
import json
import os
import re
import shlex
import sys
import time
import warnings
import zipfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import TYPE_CHECKING, Any

import click

if TYPE_CHECKING:  # numpy is imported by the commands that need it: `btel --help` does not wait for it
    import numpy as np

from .. import __version__
from ._outputs import refuse_existing
from ._params import _param_text, _param_value

#: Errors that end a command with one line and exit 1, besides btel's own (added when handling, so that
#: btel.exceptions is imported only then): what a hostile or damaged input file can still raise from a
#: library (zip, csv, deep nesting, huge numbers, missing keys).
_LIBRARY_INPUT_ERRORS = (OSError, ValueError, zipfile.BadZipFile, csv.Error, RecursionError, OverflowError,
                         LookupError, MemoryError, EOFError)

# btel.exceptions (and through it scikit-learn) is imported only when an error is being handled, so
# that `btel --help` starts in a fraction of a second.
#: Exit status of a finished evaluate/demo run in which some method did not fit or failed.
EXIT_SOME_ROWS_FAILED = 3
#: Exit status after Ctrl-C (128 + SIGINT, what a shell reports for an interrupted program).
EXIT_INTERRUPTED = 130


def _show_warning(message: Any, category: type, filename: str, lineno: int, file: Any = None,
                  line: str | None = None) -> None:
    """Warnings as one line on stderr, without the source location a user cannot act on."""
    click.echo(f"Warning: {message}", err=True)


class _Group(click.Group):
    """Turns btel's own errors into one-line messages with exit code 1."""

    def invoke(self, ctx: click.Context) -> Any:
        if not os.environ.get("BTEL_DEBUG"):
            warnings.showwarning = _show_warning
        try:
            return super().invoke(ctx)
        except (click.ClickException, click.exceptions.Exit, click.exceptions.Abort):
            raise
        except Exception as exc:
            from ..exceptions import BTELError

            if not isinstance(exc, (BTELError, *_LIBRARY_INPUT_ERRORS)) or os.environ.get("BTEL_DEBUG"):
                raise
            from ._errors import cli_message

            message = str(exc) or type(exc).__name__
            if not isinstance(exc, (BTELError, OSError, ValueError)):  # a library's error: say which
                message = f"{type(exc).__name__}: {message}"
            message = cli_message(message)
            raise click.ClickException(message.splitlines()[0] if len(message) > 2000 else message) from exc


def _load_matrix(path: str, what: str) -> np.ndarray:
    from ..descriptors.npy import load_descriptor_matrix

    return _load_whole_h5(path, what) if _is_whole_h5(path) else load_descriptor_matrix(path)


def _is_whole_h5(path: str) -> bool:
    from ..descriptors.npy import HDF5_SUFFIXES, split_prefix

    file, prefix = split_prefix(path)
    return prefix is None and file.suffix.lower() in HDF5_SUFFIXES


def _load_whole_h5(path: str, what: str) -> np.ndarray:
    """An hloc .h5 given without a PREFIX: refused when its images sit under several prefixes (map and
    queries in one file, hloc's usual layout), which would otherwise be read as one set."""
    from ..descriptors.npy import load_hloc_global

    X, names = load_hloc_global(path)
    counts: dict[str, int] = {}
    for name in names:
        head, slash, _ = name.partition("/")
        counts[head + slash] = counts.get(head + slash, 0) + 1
    if len(counts) > 1:
        found = ", ".join(f"{p or '(top level)'} {n} images" for p, n in counts.items())
        choices = " or ".join(f"{path}:{p}" for p in counts if p)
        raise click.UsageError(f"{path} ({what}) holds images under {len(counts)} prefixes ({found}); name the "
                               f"ones you mean, e.g. {choices}.")
    return X


def _load_map(path: str) -> np.ndarray:
    """Map descriptors for training: a folder of .npy shards, a memory-mapped .npy, an .npz or an hloc .h5."""
    if Path(path).is_dir():
        from ..datasets.shards import load_shards

        return load_shards(path)
    if _is_whole_h5(path):
        return _load_whole_h5(path, "map descriptors")
    from ..descriptors.npy import load_descriptor_matrix

    # A .npy map is memory-mapped: pages are read as the fit needs them, never copied whole.
    return load_descriptor_matrix(path, mmap_mode="r" if Path(path).suffix.lower() == ".npy" else None)


def _echo_storage(model: Any) -> None:
    from ..storage import format_bytes

    breakdown = model.storage_breakdown()
    width = max(len(k) for k in breakdown) if breakdown else 4
    summary = model.summary()  # what a budget planner chose (empty for methods with nothing to add)
    if summary:
        click.echo(summary)
    click.echo("storage breakdown:")
    for name, n in breakdown.items():
        click.echo(f"  {name:<{width}}  {n:>12,d} B")
    click.echo(f"  {'total':<{width}}  {model.nbytes:>12,d} B  ({format_bytes(model.nbytes)})")


_VALUE_HELP = ("VALUE is read as JSON when it is a JSON literal (3, 0.5, true, null, \"x\"), else kept as text "
               "(auto, float16). `btel methods --params` lists every method's parameters.")
_PARAM_HELP = "A parameter of --method, NAME=VALUE (repeatable), e.g. --param sparsity=0.05. " + _VALUE_HELP
_PARAMS_HELP = ("A parameter NAME=VALUE of every method in --methods, or METHOD:NAME=VALUE of one of them "
                "(repeatable), e.g. --param btel-r:n_regions=10. " + _VALUE_HELP)


#: Parameters set by runtime flags: given to the methods that have them, silently skipped by the others.
RUNTIME_PARAMS = frozenset({"progress", "n_jobs"})




def _valid_params(method: str) -> list[str]:
    """Parameter names of ``method`` (its ``get_params()`` keys), sorted; an unknown method is a usage error."""
    from ..methods.registry import METHODS, make_method

    if method not in METHODS:
        raise click.UsageError(f"unknown method {method!r}; choose from {', '.join(METHODS)} (see `btel methods`).")

    return sorted(make_method(method).get_params())


def _params_by_method(methods: list[str], param_texts: tuple[str, ...], *,
                      shortcuts: dict[str, tuple[str, Any]] | None = None,
                      base: dict[str, dict[str, Any]] | None = None) -> dict[str, dict[str, Any]]:
    """Each method's parameters, every name checked against its ``get_params()`` before anything is fitted.

    Layers, later ones overriding: ``base`` (per method, the command's own defaults), ``shortcuts``
    (parameter name → (option, value) of each named option given), ``--param NAME=VALUE`` (every
    method), ``--param METHOD:NAME=VALUE`` (that method). A shortcut and ``--param`` setting the same
    name, or one name given twice in one layer, is a usage error; so is a name a method does not have.
    """
    shortcuts = shortcuts or {}
    general: dict[str, Any] = {}
    targeted: dict[str, dict[str, Any]] = {}
    for text in param_texts:
        key, eq, raw = text.partition("=")
        target, _, name = key.strip().rpartition(":")
        if not eq or not name.isidentifier():
            raise click.UsageError(f"--param {text!r} is not NAME=VALUE (or METHOD:NAME=VALUE), e.g. feature_ratio=0.25.")
        if target and target not in methods:
            raise click.UsageError(f"--param {text!r} is for {target!r}, which is not a method of this run "
                                   f"({', '.join(methods)}).")
        layer = targeted.setdefault(target, {}) if target else general
        if name in layer:
            raise click.UsageError(f"--param sets {key.strip()} twice; give it once.")
        if name in shortcuts and name not in RUNTIME_PARAMS:  # a runtime flag yields to an explicit --param
            raise click.UsageError(f"{shortcuts[name][0]} and --param {key.strip()}=… both set {name}; give one of them.")
        layer[name] = _param_value(raw)
    out: dict[str, dict[str, Any]] = {}
    for method in methods:
        valid = _valid_params(method)
        for name, (option, _) in shortcuts.items():
            if name not in valid and name not in RUNTIME_PARAMS:
                raise click.UsageError(f"{option} sets parameter {name!r}, which {method} does not have; "
                                       f"{method} takes: {', '.join(valid)}.")
        given = {**general, **targeted.get(method, {})}
        for name in given:
            if name not in valid:
                hint = (f" (--param {name}=… applies to every method; write METHOD:{name}=… for one)"
                        if name in general and len(methods) > 1 else "")
                raise click.UsageError(f"{method} has no parameter {name!r}{hint}; {method} takes: {', '.join(valid)}.")
        # Runtime flags (--no-progress, --n-jobs) change how a method runs, not what it computes: they apply
        # where the method has the parameter and are ignored elsewhere, so one command line fits every method.
        applied = {n: v for n, (_, v) in shortcuts.items() if n in valid}
        out[method] = {**(base or {}).get(method, {}), **applied, **given}
    return out


@contextmanager
def _naming(method: str) -> Iterator[None]:
    """A bad parameter value found while building, fitting or evaluating ``method`` names the method."""
    from ..exceptions import InvalidParameterError

    try:
        yield
    except InvalidParameterError as exc:
        # The estimator names its class ("BTELocalizer: C must be …"); the user chose a method name.
        message = re.sub(r"^[A-Z][A-Za-z]+: ", "", str(exc))
        raise InvalidParameterError(f"{method}: {message}") from exc


@click.group(cls=_Group, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, prog_name="btel")
def main() -> None:
    """btel: visual place recognition under a storage budget (binary tree encoding, BTEL).

    \b
    Typical path:
      btel extract IMAGES_DIR -o db.npy --descriptor hog
      btel train db.npy -o map.btel.npz --budget 500KB
      btel localize map.btel.npz queries.npy -o predictions.csv
      btel evaluate --db db.npy --queries queries.npy --methods btel-c,btel-r,pq --budget 500KB --out runs/x
    Try `btel demo` first: it needs no data.
    """


_N_JOBS_HELP = ("Parallel fits (-1 = all cores), for the methods with an n_jobs parameter; the others ignore it "
                "(a runtime flag: it changes how a method runs, not what it computes).")
_NO_PROGRESS_HELP = ("No progress bars (btel's own and those of the methods with a progress parameter; the others "
                     "ignore it).")

_TIMING_THREADS_HELP = ("BLAS/OpenMP threads while localizing and timing the queries (the table's 'threads'). Default 1: "
                        "on a shared machine multi-threaded calls spin against other processes and identical runs "
                        "differ by 2-100x; 0 leaves the libraries' own thread count.")
_BUDGET_HELP = ("Byte budget of every method but the brute-force reference, e.g. 500KB (KB = 1000 B, KiB = 1024 B); "
                "several, comma-separated (100KB,500KB), give one row per method and budget.")
_REFERENCE_HELP = ("Brute force (exact nearest neighbour over every map descriptor) is the unbudgeted reference: it is "
                   "always run without a budget, added when not in --methods, and marked '*' in the table. "
                   "--no-reference leaves it out.")
_ORDER_HELP = ("route: the query rows are consecutive frames of one traverse (methods that use the query sequence, "
               "SeqSLAM or a delta front end, may use their order; they are marked † in the table). independent: the "
               "rows are unrelated places, and sequence methods are refused.")


@main.command()
@click.option("--places", "n_places", default=2000, show_default=True, help="Places on the synthetic route.")
@click.option("--dim", default=512, show_default=True, help="Descriptor dimension.")
@click.option("--budget", default="64KB", show_default=True, help=_BUDGET_HELP)
@click.option("--methods", default="btel-c,btel-r,btel-codes,pq,bruteforce", show_default=True,
              help="Comma-separated method names (see `btel methods`).")
@click.option("--no-reference", is_flag=True, help=_REFERENCE_HELP)
@click.option("--seed", default=0, show_default=True, help="Random seed of the route.")
@click.option("--param", "param_texts", multiple=True, metavar="[METHOD:]NAME=VALUE", help=_PARAMS_HELP)
@click.option("--out", "out_dir", type=click.Path(file_okay=False), default=None,
              help="Run folder for metrics.json, CSV and plots (default: runs/demo-<time>).")
@click.option("--overwrite", is_flag=True, help="Replace the run files in an existing run folder.")
@click.option("--no-progress", is_flag=True, help=_NO_PROGRESS_HELP)
@click.option("--n-jobs", type=int, default=None, help=_N_JOBS_HELP)
@click.option("--timing-threads", type=click.IntRange(min=0), default=1, show_default=True, help=_TIMING_THREADS_HELP)
@click.pass_context
def demo(ctx: click.Context, n_places: int, dim: int, budget: str, methods: str, no_reference: bool, seed: int,
         param_texts: tuple[str, ...], out_dir: str | None, overwrite: bool, no_progress: bool,
         n_jobs: int | None, timing_threads: int) -> None:
    """Run the main job on the embedded default: a synthetic route, several methods, a table and a plot.

    The route is generated by btel itself (btel.datasets.synthetic_route): a map traverse and a
    query traverse under an appearance change, frame-aligned. Every method gets --budget except
    brute force, the unbudgeted reference (see --no-reference); the same rule as `btel evaluate`.
    A method that does not fit the budget becomes a row saying so; exit status 3 then.
    """
    from ..datasets import synthetic_route

    budgets = _budgets(budget)
    route = synthetic_route(n_places, dim, seed=seed)
    out = Path(out_dir) if out_dir else Path("runs") / time.strftime("demo-%Y%m%d-%H%M%S")
    jobs = _fit_jobs(_split(methods), budgets, param_texts, reference=not no_reference,
                     shortcuts=_runtime_shortcuts(no_progress, n_jobs))
    from ..runs import check_run_folder

    check_run_folder(out, overwrite)
    click.echo(f"synthetic route: N = {n_places} places, d = {dim}, map + 1 query traverse (seed {seed})")
    title = (f"synthetic route (seed {seed}): N = {n_places}, d = {dim}; budget {_budget_text(budgets)}; "
             "frame-aligned")
    failed = _run_jobs(jobs, route.map, route.queries, ground_truth=None, out=out, overwrite=overwrite,
                       title=title, extra={"data": "synthetic_route", "seed": seed, "budget": budgets},
                       progress=not no_progress, timing_threads=timing_threads or None)
    if failed:
        ctx.exit(EXIT_SOME_ROWS_FAILED)


_DELTA_HELP = ("Delta (sequence) descriptors over W frames (Garg & Milford 2020): every method's front end turns a "
               "traverse into mean(last W frames) − mean(the W before), causally; queries are then one ordered "
               "traverse and the method is marked † (uses the query sequence). Same as --param delta=W.")
_FRONT_END_HELP = ("Front end of every method (default: rows L2-normalised, SeqSLAM: none): --normalize none|l2|power, "
                   "--whiten P (PCA-whitening to P dims, counted in the bytes), --delta W.")


@main.command()
@click.argument("images_dir", type=click.Path(file_okay=False))
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False), help="Descriptor matrix to write (.npy).")
@click.option("--descriptor", default="hog", show_default=True,
              help="hog | patchnorm | densevlad, or a descriptor file saved with --save-descriptor.")
@click.option("--size", default=None, metavar="WxH",
              help="hog / patchnorm: the thumbnail every image is resized to, whatever its aspect (default 64x32, "
                   "Nordland's; a Warning says when it stretches the images, e.g. use 56x32 for 16:9 frames).")
@click.option("--param", "param_texts", multiple=True, metavar="NAME=VALUE",
              help="A parameter of the descriptor, e.g. --param n_components=256 or --param n_clusters=64 "
                   "(densevlad: PCA to n_components, capped at the number of map images − 1, with a Warning). "
                   + _VALUE_HELP)
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
    from ..descriptors.extract import extract_cached
    from ..storage import format_bytes

    if split_dataset_folder(images_dir) is not None:
        root = Path(images_dir)
        raise click.UsageError(
            f"{images_dir} is a VPR-methods-evaluation data set (database/ and queries/): describe each folder, "
            f"`btel extract {root / 'database'} -o db.npy --save-descriptor d.npz` then `btel extract "
            f"{root / 'queries'} -o q.npy --descriptor d.npz`, and evaluate with --ground-truth utm.")

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
        _extract_delta(images_dir, output, model, fit_on, no_progress, force, delta)
        return
    if Path(output).exists() and not overwrite and not _is_cache_of(output, images_dir, model, fit_on):
        refuse_existing(output, "-o", overwrite)
    X, reused = extract_cached(images_dir, output, model, fit_on=fit_on, progress=not no_progress, force=force)
    if reused:
        click.echo(f"{output} is up to date ({X.shape[0]} images, {descriptor}); use --force to recompute")
        return
    resize = getattr(model, "thumbnail_size", None)
    how = f" (every image resized to {resize[0]}×{resize[1]})" if resize else ""
    click.echo(f"{X.shape[0]} images → {X.shape[1]}-D {type(model).__name__} descriptors{how} written to {output}")
    if save_descriptor:
        path = model.save(save_descriptor)
        parts = ", ".join(f"{k} {format_bytes(v.nbytes)}" for k, v in model._stored_arrays().items())
        click.echo(f"fitted descriptor written to {path} ({format_bytes(path.stat().st_size)}"
                   f"{': ' + parts if parts else ''})")


def _is_cache_of(output: str, images_dir: str, model: Any, fit_on: str | None) -> bool:
    """``output`` was written by an extraction of these images with this descriptor (its JSON sidecar says so):
    reusing or recomputing it replaces nothing."""
    from ..descriptors.extract import extraction_key, same_extraction
    from ..descriptors.images import list_images

    sidecar = Path(str(output) + ".json")
    try:
        return same_extraction(json.loads(sidecar.read_text()), extraction_key(list_images(images_dir), model, fit_on))
    except (OSError, ValueError):
        return False


def _extract_delta(images_dir: str, output: str, model: Any, fit_on: str | None, no_progress: bool, force: bool,
                   window: int) -> None:
    """``extract --delta W``: the plain descriptors (cached beside OUTPUT), then their delta, written to OUTPUT."""
    import numpy as np

    from ..descriptors import delta_descriptors
    from ..descriptors.extract import extract_cached

    plain = Path(output).with_name(Path(output).stem + ".plain.npy")
    X, _ = extract_cached(images_dir, plain, model, fit_on=fit_on, progress=not no_progress, force=force)
    D = delta_descriptors(X, window)
    Path(output).parent.mkdir(parents=True, exist_ok=True)
    np.save(output, D)
    click.echo(f"{X.shape[0]} images → {D.shape[1]}-D delta descriptors (W = {window}) of {type(model).__name__} "
               f"written to {output} (plain descriptors kept in {plain})")


@main.command()
@click.argument("db", type=click.Path())
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False), help="Model file to write (.npz).")
@click.option("--overwrite", is_flag=True, help="Replace an existing OUTPUT model file.")
@click.option("--method", default="auto", show_default=True, help="Method name (see `btel methods`).")
@click.option("--budget", default=None, help="Byte budget, e.g. 500KB, 2MB, 64KiB.")
@click.option("--param", "param_texts", multiple=True, metavar="NAME=VALUE", help=_PARAM_HELP)
@click.option("--regions", default=None, help="BTEL: number of regions r, or 'auto'.")
@click.option("--feature-ratio", type=float, default=None, help="BTEL: c = d'/d.")
@click.option("--n-features", type=int, default=None, help="BTEL: d' directly.")
@click.option("--classifier", type=click.Choice(["svm", "logistic"]), default=None, help="BTEL classifier.")
@click.option("--dtype", type=click.Choice(["float32", "float16"]), default=None, help="BTEL stored weight dtype.")
@click.option("--n-jobs", type=int, default=None, help=_N_JOBS_HELP)
@click.option("--backend", type=click.Choice(["threads", "loky", "dask"]), default=None,
              help="BTEL: where the classifier fits run — threads (default), loky processes, or a Dask cluster "
                   "(pip install btel[dask]).")
@click.option("--scheduler", default=None, help="With --backend dask: the scheduler address, e.g. tcp://10.0.0.5:8786.")
@click.option("--no-progress", is_flag=True, help=_NO_PROGRESS_HELP)
@click.option("--seed", "random_state", type=int, default=None, help="Random seed (random_state).")
@click.option("--block-size", type=int, default=None,
              help="BTEL: tolerance-aware codes, index blocks of B places and answer the block centre.")
@click.option("--tolerance", type=int, default=None,
              help="BTEL: the tolerance t you need (frames); sets --block-size to the largest power of two ≤ t.")
@click.option("--code-copies", type=int, default=None, help="BTEL: offset (error-correcting) codes, m copies.")
@click.option("--exemplar-radius", type=int, default=None, help="BTEL: multi-exemplar weights within ±e places.")
@click.option("--normalize", type=click.Choice(["none", "l2", "power"]), default=None, help=_FRONT_END_HELP)
@click.option("--whiten", type=int, default=None, metavar="P", help="PCA-whiten to P dimensions (front end).")
@click.option("--delta", type=int, default=None, metavar="W", help=_DELTA_HELP)
def train(db: str, output: str, overwrite: bool, method: str, budget: str | None, param_texts: tuple[str, ...], regions: str | None,
          feature_ratio: float | None, n_features: int | None, classifier: str | None, dtype: str | None,
          n_jobs: int | None, backend: str | None, scheduler: str | None, no_progress: bool,
          random_state: int | None, block_size: int | None, tolerance: int | None, code_copies: int | None,
          exemplar_radius: int | None, normalize: str | None, whiten: int | None, delta: int | None) -> None:
    """Fit a model on map descriptors DB and save it; prints the storage breakdown.

    DB is a .npy matrix (row i = place i; memory-mapped, so maps larger than RAM work), an .npz,
    or a folder of .npy shards taken in natural file-name order (shard_2 before shard_10).

    \b
    Any parameter of --method is set with --param NAME=VALUE, e.g.
      btel train db.npy -o m.npz --method pq --param n_subquantizers=16 --param nbits=8

    --budget and the options after --param are shortcuts that fill the same parameters (--regions
    is n_regions, --seed random_state, --no-progress progress=false, --block-size and --tolerance
    block_size, the others by their own names). Each must be a parameter of --method (see `btel
    methods --params`), and a shortcut and --param may not set the same one.
    """
    from ..methods.registry import make_method

    if scheduler is not None and backend != "dask":
        raise click.UsageError("--scheduler only applies with --backend dask.")
    if block_size is not None and tolerance is not None:
        raise click.UsageError("give --block-size or --tolerance, not both.")
    if tolerance is not None:
        from ..methods.btel.localizer import block_size_for_tolerance

        block_size = block_size_for_tolerance(tolerance)
    n_regions: Any = None
    if regions is not None:
        n_regions = regions if regions == "auto" else _int(regions, "--regions")
    named = {"budget": ("--budget", budget), "n_regions": ("--regions", n_regions),
             "feature_ratio": ("--feature-ratio", feature_ratio), "n_features": ("--n-features", n_features),
             "classifier": ("--classifier", classifier), "dtype": ("--dtype", dtype), "n_jobs": ("--n-jobs", n_jobs),
             "backend": ("--backend", backend), "scheduler": ("--scheduler", scheduler),
             "progress": ("--no-progress", False if no_progress else None),
             "random_state": ("--seed", random_state),
             "block_size": ("--tolerance" if tolerance is not None else "--block-size", block_size),
             "code_copies": ("--code-copies", code_copies), "exemplar_radius": ("--exemplar-radius", exemplar_radius),
             "normalize": ("--normalize", normalize), "whiten": ("--whiten", whiten), "delta": ("--delta", delta)}
    shortcuts = {name: (option, value) for name, (option, value) in named.items() if value is not None}
    if budget is not None:
        _check_budget(budget)
    params = _params_by_method([method], param_texts, shortcuts=shortcuts)[method]
    refuse_existing(output, "-o", overwrite)
    X = _load_map(db)
    start = time.perf_counter()
    with _naming(method):
        model = make_method(method, **params)
        model.fit(X)
    regions = f", r = {model.n_regions_} regions" if getattr(model, "n_regions_", 1) > 1 else ""
    click.echo(f"fitted {method}{regions} on {X.shape[0]} places × {X.shape[1]} dims "
               f"in {time.perf_counter() - start:.1f} s")
    _echo_storage(model)
    path = model.save(output)
    click.echo(f"model written to {path} ({path.stat().st_size:,d} B on disk)")


@main.command()
@click.argument("model_path", metavar="MODEL", type=click.Path(dir_okay=False))
@click.argument("queries", required=False, type=click.Path(dir_okay=False))
@click.option("-o", "--output", type=click.Path(dir_okay=False), help="Predictions CSV to write (not with --stream).")
@click.option("--overwrite", is_flag=True, help="Replace an existing OUTPUT predictions file.")
@click.option("--sequence-filter", "window", type=int, default=None,
              help="Apply the paper's sequence filter with window a (queries must be consecutive frames).")
@click.option("--stream", is_flag=True,
              help="Read one descriptor per line (numbers separated by commas/spaces) from stdin or --input and "
                   "print one prediction per line as each arrives.")
@click.option("--input", "input_path", type=click.Path(dir_okay=False), default=None,
              help="With --stream: read this text file instead of stdin.")
@click.option("--hmm", is_flag=True,
              help="Decode the queries as one ordered traverse with the HMM over places (forward motion; no extra "
                   "stored bytes) instead of frame by frame; online (one update per frame) with --stream.")
@click.option("--top-k", type=int, default=None,
              help="Batch: also write the K most likely places per query (ranked output) as columns rank_1…rank_K.")
@click.option("--follow", is_flag=True, help="With --stream --input: keep reading as the file grows (like tail -f).")
@click.option("--idle-timeout", type=float, default=None,
              help="With --follow: stop after this many seconds without a new line (default: run until Ctrl-C).")
def localize(model_path: str, queries: str | None, output: str | None, overwrite: bool, window: int | None, stream: bool,
             input_path: str | None, hmm: bool, top_k: int | None, follow: bool, idle_timeout: float | None) -> None:
    """Predict the place of every query with a saved MODEL.

    \b
    Batch:  btel localize MODEL QUERIES.npy -o predictions.csv   (writes query,prediction CSV)
    Stream: producer | btel localize MODEL --stream --sequence-filter 5   (or --hmm)
            btel localize MODEL --stream --input frames.txt --follow
    In stream mode each line of input is one descriptor; each output line is the place index of the
    next well-formed input line. A malformed line (wrong count, not a number, NaN) gets a one-line
    error naming its line number on stderr, produces no output line, and the stream goes on.
    """
    from .. import load
    from ..sequence import filter_sequence

    if stream:
        if top_k is not None:
            raise click.UsageError("--top-k applies to batch localization, not --stream.")
        if hmm and window is not None:
            raise click.UsageError("choose --hmm or --sequence-filter, not both.")
        if queries is not None or output is not None:
            raise click.UsageError("--stream reads stdin (or --input) and writes stdout; drop QUERIES and -o.")
        _localize_stream(load(model_path), input_path, follow, idle_timeout, window, hmm)
        return
    if input_path is not None or follow or idle_timeout is not None:
        raise click.UsageError("--input, --follow and --idle-timeout only apply with --stream.")
    if queries is None or output is None:
        raise click.UsageError("give QUERIES and -o/--output (or use --stream).")
    if hmm and window is not None:
        raise click.UsageError("choose --hmm or --sequence-filter, not both.")
    refuse_existing(output, "-o", overwrite)
    model = load(model_path)
    Q = _load_matrix(queries, "query descriptors")
    if top_k is not None and not getattr(model, "supports_ranking", True):
        raise click.UsageError(f"{type(model).__name__} does not rank candidates; drop --top-k.")
    predictions = model.predict_sequence(Q, "hmm") if hmm else model.predict(Q)
    if window is not None:
        predictions = filter_sequence(predictions, window, n_places=model.n_places_)
    ranked = model.rank(Q, top_k) if top_k is not None else None
    Path(output).parent.mkdir(parents=True, exist_ok=True)
    with open(output, "w", newline="") as fh:
        writer = csv.writer(fh)
        head = ["query", "prediction"]
        if ranked is not None:
            head += [f"rank_{j + 1}" for j in range(ranked.shape[1])]
        writer.writerow(head)
        for i, p in enumerate(predictions.tolist()):
            writer.writerow([i, p, *(ranked[i].tolist() if ranked is not None else [])])
    click.echo(f"{len(predictions)} predictions written to {output}")


def _localize_stream(model: Any, input_path: str | None, follow: bool, idle_timeout: float | None,
                     window: int | None, hmm: bool = False) -> None:
    """The --stream loop: one flushed output line per well-formed input line."""
    from ..streaming import localize_stream

    if follow and input_path is None:
        raise click.UsageError("--follow needs --input FILE (stdin already waits for new lines).")
    if idle_timeout is not None and not follow:
        raise click.UsageError("--idle-timeout only applies with --follow.")
    n_bad = n_out = 0

    def report(line_number: int, message: str) -> None:
        nonlocal n_bad
        n_bad += 1
        click.echo(f"error: line {line_number}: {message} (skipped)", err=True)

    # Bytes, decoded line by line in localize_stream: a byte that is not UTF-8 is one malformed line,
    # not the end of the stream (a text stream's decoder would raise and stop it).
    source = open(input_path, "rb") if input_path is not None else getattr(sys.stdin, "buffer", sys.stdin)
    try:
        for _, place in localize_stream(model, source, window=window, on_error=report, follow=follow,
                                        idle_timeout=idle_timeout, hmm=hmm):
            click.echo(place)  # click.echo flushes: a reader of the pipe sees each line at once
            n_out += 1
    except KeyboardInterrupt:  # stopping a --follow stream is the normal way to end it
        pass
    finally:
        if input_path is not None:
            source.close()
    if n_bad:
        click.echo(f"{n_out} predictions; {n_bad} malformed line(s) skipped", err=True)


@main.command(name="evaluate")
@click.option("--db", type=click.Path(dir_okay=False), default=None,
              help="Map descriptors to fit --methods on: .npy, .npz (FILE.npz:KEY names the array), or hloc global "
                   "features FILE.h5 (FILE.h5:PREFIX keeps images whose name starts with PREFIX). Row i = place i.")
@click.option("--model", "model_paths", multiple=True, type=click.Path(dir_okay=False),
              help="A saved model to evaluate instead of fitting (repeatable).")
@click.option("--queries", required=True, type=click.Path(dir_okay=False),
              help="Query descriptors, one query per row (same formats as --db).")
@click.option("--methods", default="auto", show_default=True, help="Comma-separated method names (with --db).")
@click.option("--budget", default=None, help=_BUDGET_HELP)
@click.option("--no-reference", is_flag=True, help=_REFERENCE_HELP)
@click.option("--param", "param_texts", multiple=True, metavar="[METHOD:]NAME=VALUE", help=_PARAMS_HELP)
@click.option("--ground-truth", type=click.Path(dir_okay=False), default=None,
              help="Which map places are correct for each query. Default: frame-aligned (query j is place j). "
                   "Files: .npz (query_places; indptr+indices positives; utmDb+utmQ+posDistThr), .npy (1-D true "
                   "places, or VPR-Bench's ground_truth_new.npy object array), .mat (NetVLAD dbStruct), "
                   ".csv (header query,positive: one pair per line). 'utm': VPR-methods-evaluation data (images "
                   "named @utm_east@utm_north@…, described with btel extract DATASET/database and DATASET/queries): "
                   "positives within --positive-dist-threshold metres.")
@click.option("--positive-dist-threshold", type=float, default=None, metavar="METRES",
              help="With --ground-truth utm: map images within this many metres of a query are its positives "
                   "(default 25, VPR-methods-evaluation's).")
@click.option("--pairs", "pairs_path", type=click.Path(dir_okay=False), default=None,
              help="Also write an hloc retrieval pairs file (query_name db_name per line, each query's top K of the "
                   "largest --k, best first); with several methods one file each, FILE-<method>.txt. Names come "
                   "from the inputs (btel extract's .json, hloc .h5), else row numbers.")
@click.option("--tolerances", default=None, metavar="T,T,…",
              help="recall@t tolerances in frames (one true place per query only). Default: 0,1,2,5,10,20 up "
                   "to a tenth of the map (0,1,2,5,10 on a 111-place route).")
@click.option("--k", "ks_text", default="1,5,10,20", show_default=True, metavar="K,K,…",
              help="R@K: a correct place among the top K ranked candidates (every method ranks; R@1 is the point "
                   "prediction). With explicit positives R@K is the only metric.")
@click.option("--query-order", type=click.Choice(["route", "independent"]), default="route", show_default=True,
              help=_ORDER_HELP)
@click.option("--out", "out_dir", type=click.Path(file_okay=False), default=None,
              help="Run folder (required unless --resume).")
@click.option("--overwrite", is_flag=True, help="Replace the run files in an existing run folder.")
@click.option("--resume", "resume_dir", type=click.Path(file_okay=False), default=None, metavar="RUN",
              help="Go on with the run folder RUN (interrupted with Ctrl-C): the rows already done (status ok) are "
                   "kept and not run again, the others run. Give the same --db/--model/--queries and options.")
@click.option("--normalize", type=click.Choice(["none", "l2", "power"]), default=None,
              help="Every method's front-end normalisation (default l2; SeqSLAM none). Same as --param normalize=…")
@click.option("--whiten", type=int, default=None, metavar="P",
              help="Every method: PCA-whiten to P dimensions (counted in its bytes). Same as --param whiten=P.")
@click.option("--delta", type=int, default=None, metavar="W", help=_DELTA_HELP)
@click.option("--no-progress", is_flag=True, help=_NO_PROGRESS_HELP)
@click.option("--n-jobs", type=int, default=None, help=_N_JOBS_HELP)
@click.option("--timing-threads", type=click.IntRange(min=0), default=1, show_default=True, help=_TIMING_THREADS_HELP)
@click.pass_context
def evaluate_cmd(ctx: click.Context, db: str | None, model_paths: tuple[str, ...], queries: str, methods: str,
                 budget: str | None, no_reference: bool, param_texts: tuple[str, ...], ground_truth: str | None,
                 positive_dist_threshold: float | None, pairs_path: str | None, tolerances: str | None, ks_text: str, query_order: str, out_dir: str | None, overwrite: bool,
                 resume_dir: str | None,
                 normalize: str | None, whiten: int | None, delta: int | None, no_progress: bool,
                 n_jobs: int | None, timing_threads: int) -> None:
    """Localize QUERIES with each method and write metrics.json, metrics.csv, predictions and plots to --out.

    Methods are fitted on --db (by name, --methods, each with --budget and its --param values), or
    loaded from saved --model files (which keep the parameters they were fitted with).

    \b
    Before anything is fitted: the run folder, the ground truth against the query and map
    counts, and every method against its budget are checked, and every method that cannot run
    is listed at once. A method that does not fit (or fails) becomes a row with its status and
    reason; every other row is kept. metrics.json / metrics.csv are rewritten as each method
    finishes, so a crash or Ctrl-C keeps what is done.
    Exit status: 0 every row ran; 3 the run finished but some row did not fit or failed;
    1 bad data; 2 bad usage.

    \b
    Metrics: recall@t = the point prediction within t frames of the true place (frame-aligned
    or one-true-place ground truth); R@K = a correct place among the top K candidates.
    Methods marked † use the query sequence (SeqSLAM, delta front ends): not comparable with
    single-frame methods.
    """
    from .. import load
    from ..datasets import GroundTruth
    from ..evaluation import Job, check_ground_truth
    from ..runs import check_run_folder

    if db is None and not model_paths:
        raise click.UsageError("give --db (to fit --methods) or at least one --model.")
    if resume_dir is not None and out_dir is not None and Path(out_dir) != Path(resume_dir):
        raise click.UsageError("--resume RUN writes into RUN; drop --out (or give the same folder).")
    if resume_dir is not None and overwrite:
        raise click.UsageError("--resume keeps the rows of RUN; --overwrite would replace them. Give one.")
    if out_dir is None and resume_dir is None:
        raise click.UsageError("give --out RUN_FOLDER (or --resume RUN to go on with an interrupted run).")
    out_dir = out_dir or resume_dir
    if param_texts and db is None:
        raise click.UsageError("--param sets parameters of the methods fitted on --db; saved --model files keep theirs.")
    budgets = _budgets(budget) if budget else [None]
    ks = _int_list(ks_text, "--k", minimum=1)
    tolerance_list = _int_list(tolerances, "--tolerances", minimum=0) if tolerances is not None else None
    front = {name: (f"--{name}", value) for name, value in
             (("normalize", normalize), ("whiten", whiten), ("delta", delta)) if value is not None}
    if front and db is None:
        raise click.UsageError("--normalize/--whiten/--delta set the front end of methods fitted on --db; saved "
                               "--model files keep theirs.")
    jobs = _fit_jobs(_split(methods), budgets, param_texts, reference=not no_reference,
                     shortcuts={**front, **_runtime_shortcuts(no_progress, n_jobs)}) \
        if db is not None else []
    # Cheap checks first, so that nothing is fitted for a run that cannot be written or scored.
    finished = _finished_rows(resume_dir, queries) if resume_dir is not None else None
    if finished is None:
        check_run_folder(Path(out_dir), overwrite)
    Q = _load_matrix(queries, "query descriptors")
    X = None
    if db is not None:
        X = _load_matrix(db, "map descriptors")
        if X.shape[1] != Q.shape[1]:
            raise click.ClickException(
                f"--db has {X.shape[1]} dims but --queries has {Q.shape[1]}; describe both with the same descriptor.")
    saved = []
    for path in model_paths:
        model = load(path)
        if model.n_features_in_ != Q.shape[1]:
            raise click.ClickException(f"--model {path} expects {model.n_features_in_}-D descriptors but --queries "
                                       f"has {Q.shape[1]}.")
        saved.append(Job(Path(path).name.split(".")[0], model, fit=False))
    n_maps = {int(j.method.n_places_) for j in saved} | ({X.shape[0]} if X is not None else set())
    if len(n_maps) > 1:
        raise click.ClickException(f"the maps differ in size ({sorted(n_maps)} places): --db and every --model "
                                   "must cover the same map for one ground truth to hold.")
    n_map = n_maps.pop()
    if positive_dist_threshold is not None and ground_truth != "utm":
        raise click.UsageError("--positive-dist-threshold applies with --ground-truth utm (positions in the image "
                               "names); a ground-truth file says its own positives.")
    if positive_dist_threshold is not None and not positive_dist_threshold > 0:
        raise click.UsageError(f"--positive-dist-threshold must be > 0 metres; got {positive_dist_threshold:g}.")
    if ground_truth == "utm":
        from ..datasets.vpr_names import DEFAULT_POSITIVE_DIST_THRESHOLD
        from ._names import utm_ground_truth

        if db is None:
            raise click.UsageError("--ground-truth utm reads the map's image names from --db; give --db.")
        threshold = DEFAULT_POSITIVE_DIST_THRESHOLD if positive_dist_threshold is None else positive_dist_threshold
        given = utm_ground_truth(db, queries, n_map, Q.shape[0], threshold)
    else:
        given = GroundTruth.from_file(ground_truth) if ground_truth else None
    gt = check_ground_truth(given, Q.shape[0], n_map, option="--ground-truth")
    if tolerance_list is not None and not gt.uses_tolerance:
        raise click.UsageError("--tolerances needs one true place per query; --ground-truth lists explicit "
                               "positives, which have no tolerance. Use --k (R@K) instead.")
    truth = ("frame-aligned" if ground_truth is None else
             f"positives within {threshold:g} m (UTM in the image names)" if ground_truth == "utm" else
             f"{'one true place per query' if gt.uses_tolerance else 'positives'} from {Path(ground_truth).name}")
    dataset = Path(db if db else queries).name.split(".")[0]
    budget_part = (f"budget {_budget_text(budgets)}" if any(budgets) else
                   "saved models" + (" and unbudgeted methods" if jobs else "") if saved else "no budget")
    title = f"{dataset}: N = {n_map}, {Q.shape[0]} queries; {budget_part}; {truth}"
    click.echo(f"map: N = {n_map} places; queries: {Q.shape[0]} × {Q.shape[1]}; ground truth: {truth}")
    from ._gallery import input_names

    pairs, names = None, input_names(db, queries, n_map, Q.shape[0])
    if pairs_path is not None:
        from ._names import pairs_paths

        targets = pairs_paths(pairs_path, [j.name for j in saved + jobs])
        for target in targets.values():
            refuse_existing(target, "--pairs", overwrite)
        pairs = (targets, names[0] or [str(i) for i in range(Q.shape[0])], names[1] or [str(i) for i in range(n_map)])
    failed = _run_jobs(saved + jobs, X, Q, ground_truth=gt, out=Path(out_dir), overwrite=overwrite, title=title,
                       pairs=pairs, names=names,
                       tolerances=tolerance_list, ks=ks, queries_are_route=query_order == "route",
                       progress=not no_progress, finished=finished, timing_threads=timing_threads or None,
                       extra={"db": str(Path(db).resolve()) if db else None, "models": list(model_paths),
                              "queries": str(Path(queries).resolve()), "budget": budgets,
                              "ground_truth": str(Path(ground_truth).resolve()) if ground_truth else "frame-aligned",
                              "query_order": query_order})
    if failed:
        ctx.exit(EXIT_SOME_ROWS_FAILED)


def _finished_rows(run: str, queries: str) -> list[Any]:
    """The rows of the run folder ``run`` to keep (``--resume``), after checking it ran on ``queries``."""
    from ..runs import read_unfinished_run

    meta, rows = read_unfinished_run(run)
    before = (meta.get("extra") or {}).get("queries")
    if before is not None and before != str(Path(queries).resolve()):
        raise click.UsageError(f"--resume {run}: that run localized {before}, not {queries}; give the same "
                               "--queries (and --db/--model, options) as the interrupted run.")
    done = [r for r in rows if r.ok]
    click.echo(f"resuming {run}: {len(done)} of {len(rows)} rows done ({', '.join(r.name for r in done) or 'none'}); "
               "the others run now")
    return done


def _runtime_shortcuts(no_progress: bool, n_jobs: int | None) -> dict[str, tuple[str, Any]]:
    """The runtime flags given, as shortcuts (parameter → (option, value)) for :func:`_params_by_method`."""
    out: dict[str, tuple[str, Any]] = {}
    if no_progress:
        out["progress"] = ("--no-progress", False)
    if n_jobs is not None:
        out["n_jobs"] = ("--n-jobs", n_jobs)
    return out


def _budgets(text: str) -> list[str]:
    """``"100KB, 500KB"`` → ``["100KB", "500KB"]``, each checked by :func:`btel.storage.parse_budget`."""
    from ..storage import parse_budget

    budgets = [b.strip() for b in text.split(",") if b.strip()]
    if not budgets:
        raise click.UsageError("--budget is empty; give a byte budget such as 500KB.")
    for b in budgets:
        _check_budget(b)
    return budgets


def _check_budget(text: str) -> None:
    """A usage error for a budget that is not one, or a unitless number too small to be meant as bytes."""
    from ..storage import parse_budget
    from ._errors import unitless_budget_hint

    hint = unitless_budget_hint(text)
    if hint is not None:
        raise click.UsageError(f"--budget {text.strip()} has no unit, so it would mean {text.strip()} bytes; did you "
                               f"mean {hint}? Write {text.strip()}B if you mean bytes (KB = 1000 B, KiB = 1024 B).")
    try:
        parse_budget(text)
    except ValueError as exc:
        raise click.UsageError(f"--budget {text!r}: {exc}") from None


def _budget_text(budgets: list[str | None]) -> str:
    from ..storage import format_bytes, parse_budget

    given = [format_bytes(parse_budget(b)) for b in budgets if b]
    return ", ".join(given) if given else "none"


def _int_list(text: str, flag: str, *, minimum: int) -> list[int]:
    try:
        values = sorted({int(v) for v in text.split(",") if v.strip()})
    except ValueError:
        raise click.UsageError(f"{flag} takes comma-separated integers, e.g. 1,5,10; got {text!r}.") from None
    if not values or values[0] < minimum:
        raise click.UsageError(f"{flag} takes integers ≥ {minimum}; got {text!r}.")
    return values


def _fit_jobs(names: list[str], budgets: list[str | None], param_texts: tuple[str, ...], *,
              reference: bool, shortcuts: dict[str, tuple[str, Any]] | None = None) -> list[Any]:
    """One job per (method, budget); brute force once, unbudgeted, as the reference row.

    The rule (the same in demo and evaluate): brute force stores every map descriptor, so it is the
    upper reference, not a contender under the budget. It is run without a budget unless
    ``--param bruteforce:budget=…`` asks for one.
    """
    from ..evaluation import Job
    from ..methods.registry import make_method

    if reference and "bruteforce" not in names:
        names = [*names, "bruteforce"]
    params = _params_by_method(names, param_texts, shortcuts=shortcuts)
    jobs = []
    for name in names:
        is_reference = name == "bruteforce" and "budget" not in params[name]
        for budget in ([None] if is_reference else budgets):
            label = name if len(budgets) == 1 or is_reference else f"{name}@{budget}"
            kwargs = dict(params[name])
            if budget is not None and "budget" not in kwargs:
                kwargs["budget"] = budget
            settings = {k: v for k, v in params[name].items() if k != "budget" and k not in RUNTIME_PARAMS}
            with _naming(name):
                jobs.append(Job(label, make_method(name, **kwargs), reference=is_reference, series=name,
                                settings=settings or None))
    return jobs


def _run_jobs(jobs: list[Any], X: Any, Q: np.ndarray, *, ground_truth: Any, out: Path, overwrite: bool, title: str,
              extra: dict[str, Any], progress: bool, tolerances: list[int] | None = None,
              finished: list[Any] | None = None, timing_threads: int | None = 1, pairs: tuple[dict[str, Path], list[str], list[str]] | None = None,
              names: tuple[list[str] | None, list[str] | None] = (None, None),
              ks: list[int] | tuple[int, ...] = (1, 5, 10, 20), queries_are_route: bool = True) -> bool:
    """Run every job through :func:`btel.evaluation.evaluate_all`, writing the run folder as rows finish.

    Prints the rows that cannot run before fitting anything, a progress bar (or one line per job
    off a terminal), the table and where the files are. Returns True when some row did not run.
    """
    from tqdm import tqdm

    from ..evaluation import evaluate_all, format_table
    from ..runs import RunWriter
    from ..storage import format_bytes

    if finished is not None:  # --resume: the finished rows and their predictions stay
        from ..runs import resume_writer

        writer = resume_writer(out, finished, command=_command_line(), extra=extra)
    else:
        writer = RunWriter(out, command=_command_line(), extra=extra, overwrite=overwrite)
    writer.query_names, writer.db_names = names  # image names in the predictions files
    unit = "frames" if queries_are_route else "map places"  # no "frames" on independent places
    bar = tqdm(total=len(jobs), unit="method", disable=None if progress else True, leave=False, file=sys.stderr)

    def on_preflight(skipped: dict[str, Any]) -> None:
        if skipped:
            click.echo(f"{len(skipped)} of {len(jobs)} rows cannot run (found before fitting; every other row runs):")
            for name, r in skipped.items():
                click.echo(f"  {name}: {r.status}: {r.reason}")
            bar.update(len(skipped))

    def on_start(index: int, job: Any) -> None:
        budget = job.budget
        what = f"{job.name} ({'reference, unbudgeted' if job.reference else format_bytes(budget) if budget else 'no budget'})"
        if bar.disable:
            click.echo(f"[{index + 1}/{len(jobs)}] {'fitting' if job.fit else 'evaluating'} {what} …")
        else:
            bar.set_description_str(what)

    latest: list[Any] = []

    def on_result(rows: list[Any]) -> None:
        latest[:] = rows
        writer.write(rows)
        if rows and not bar.disable:
            bar.update(1)

    try:
        results = evaluate_all(jobs, X, Q, ground_truth=ground_truth, tolerances=tolerances, ks=ks,
                               queries_are_route=queries_are_route, on_preflight=on_preflight, on_result=on_result,
                               on_start=on_start, finished=finished or (), timing_threads=timing_threads)
    except KeyboardInterrupt:
        bar.close()
        _plot_partial_run(latest, out, title, unit)
        click.echo(f"interrupted: the finished rows are in {out}/metrics.csv", err=True)
        raise click.exceptions.Exit(EXIT_INTERRUPTED) from None
    bar.close()
    click.echo(format_table(results))
    report = writer.finish(results, title=title, tolerance_unit=unit)
    click.echo(f"run folder: {report.out_dir}")
    from ._gallery import galleries_after_run

    galleries_after_run(out, extra)
    if pairs is not None:
        from ._names import write_pairs

        targets, q_names, db_names = pairs
        for r in results:
            if r.name in targets and r.ok and r.ranked is not None:
                n = write_pairs(targets[r.name], r.ranked, q_names, db_names)
                click.echo(f"pairs ({r.name}, top {r.ranked.shape[1]}): {n} lines written to {targets[r.name]}")
    failed = [r for r in results if not r.ok]
    if failed:
        click.echo(f"{len(failed)} of {len(results)} rows did not run: "
                   + "; ".join(f"{r.name} ({r.status})" for r in failed) + "; see their reason in the table.", err=True)
    return bool(failed)


def _plot_partial_run(rows: list[Any], out: Path, title: str, unit: str = "frames") -> None:
    """The plots of the rows that finished before Ctrl-C (metrics.json stays ``"complete": false``)."""
    from ..plots import plot_run

    measured = [r for r in rows if r.ok]
    if not measured:
        return
    try:
        plot_run(measured, out, title=f"{title} — interrupted: {len(measured)} of {len(rows)} rows",
                 tolerance_unit=unit)
    except (ValueError, OSError) as exc:  # the rows on disk matter more than a figure
        click.echo(f"Warning: the plots of the partial run could not be drawn ({exc})", err=True)


@main.command(name="methods")
@click.option("--params", "show_params", is_flag=True,
              help="Also list each method's parameters: NAME=DEFAULT: allowed values — meaning ([runtime]: how it "
                   "runs, not what it computes; not saved with a model).")
def methods_cmd(show_params: bool) -> None:
    """List the registered methods, one line each (and, with --params, what --param can set).

    † marks methods that use the query sequence.
    """
    from ..methods.registry import DESCRIPTIONS, METHODS, make_method

    width = max(len(n) for n in METHODS)
    for name in METHODS:
        model = make_method(name)
        mark = " †" if model.uses_query_sequence else ""
        click.echo(f"{name:<{width}}  {DESCRIPTIONS.get(name, '')}{mark}")
        if show_params:
            from ._params import parameter_lines

            runtime = set(getattr(model, "_runtime_params", ()))
            for line in parameter_lines(model, runtime=runtime):
                click.echo(" " * (width + 4) + line)


def _method_names() -> list[str]:
    from ..methods.registry import METHODS

    return list(METHODS)


def _registry_name(model: Any) -> str:
    """The registry name of this model (``btel-f``) when a preset builds exactly it; else the class
    and the parameters the presets of that class differ in (``BTELocalizer (scheme=compressed, n_regions=4)``)."""
    from functools import partial

    from ..methods.registry import METHODS

    params = model.get_params(deep=False)
    keys: list[str] = []
    for name, factory in METHODS.items():
        cls = factory.func if isinstance(factory, partial) else factory
        if type(model) is not cls:
            continue
        fixed = factory.keywords if isinstance(factory, partial) else {}
        if all(params.get(k) == v for k, v in fixed.items()):
            return name
        keys += [k for k in fixed if k not in keys]
    shown = ", ".join(f"{k}={_param_text(params.get(k))}" for k in keys)
    return f"{type(model).__name__} ({shown})" if shown else type(model).__name__


@main.command()
@click.argument("model_path", metavar="MODEL", type=click.Path(dir_okay=False))
def info(model_path: str) -> None:
    """Show what a saved MODEL is: method, parameters, front end, and the bytes of every stored array."""
    from .. import load

    model = load(model_path)
    name = _registry_name(model)
    click.echo(f"method: {name}" + (f" — {type(model).__name__}" if name in _method_names() else ""))
    click.echo(f"map: N = {model.n_places_} places, d = {model.n_features_in_}")
    front = model.front_end_
    click.echo(f"front end: normalize={front.normalize}, whiten={front.whiten}, delta={front.delta}"
               f"{'  (uses the query sequence)' if model.uses_query_sequence else ''}")
    params = model.get_params(deep=False)
    runtime = set(getattr(model, "_runtime_params", ()))
    shown = {k: v for k, v in sorted(params.items()) if k not in runtime and k not in ("normalize", "whiten", "delta")}
    chosen = _chosen_at_fit(model)
    click.echo("parameters: " + ", ".join(
        f"{k}={_param_text(v)}" + (f" (chosen: {_param_text(chosen[k])})" if v is None and k in chosen else "")
        for k, v in shown.items()))
    if chosen:
        click.echo("chosen at fit: " + ", ".join(f"{k}={_param_text(v)}" for k, v in chosen.items()))
    _echo_storage(model)
    _echo_arrays(model)
    size = Path(model_path).stat().st_size
    click.echo(f"file size {size:,d} B (container overhead {size - model.nbytes:,d} B)")


def _chosen_at_fit(model: Any) -> dict[str, Any]:
    """What fitting decided (the budget planner's choices, sizes): the model's saved state, scalars only."""
    state = model._fitted_state() if callable(getattr(model, "_fitted_state", None)) else {}
    out = {}
    for key, value in state.items():
        if isinstance(value, (bool, int, float, str)) or value is None:
            out[key] = value
        elif isinstance(value, (list, tuple)) and len(value) <= 8 and all(isinstance(v, (int, float)) for v in value):
            out[key] = list(value)
    return out


def _echo_arrays(model: Any) -> None:
    """Every array the model file stores: name, shape, dtype and bytes (front end included)."""
    arrays = {**model.front_end_.arrays(), **model._stored_arrays()}
    if not arrays:
        return
    width = max(len(k) for k in arrays)
    click.echo("stored arrays:")
    for name, a in arrays.items():
        shape = " × ".join(map(str, a.shape)) or "scalar"
        click.echo(f"  {name:<{width}}  {shape:>14}  {str(a.dtype):<8} {a.nbytes:>12,d} B")


@main.command()
@click.argument("name", metavar="NAME")
@click.option("--data", "data_root", type=click.Path(file_okay=False), default=None,
              help="Folder with summer/ and winter/ (default ../shared/data/nordland64).")
@click.option("--out", "out_dir", type=click.Path(file_okay=False), default="runs/experiments", show_default=True,
              help="Runs folder; results go to OUT/NAME/.")
@click.option("--cache", "cache_dir", type=click.Path(file_okay=False), default=None,
              help="Descriptor cache (default OUT/cache).")
@click.option("--quick", is_flag=True, help="Small version (first 300 frames, few points): for tests and smoke runs.")
@click.option("--delta", type=int, default=None, metavar="W",
              help="Run every method with delta descriptors over W frames (front end; results go to "
                   "OUT/NAME-delta-W/ so they sit beside the default runs).")
def experiment(name: str, data_root: str | None, out_dir: str, cache_dir: str | None, quick: bool,
               delta: int | None) -> None:
    """Run one of the paper's experiments on Nordland (or 'all').

    \b
    NAME: accuracy | vs-n | vs-budget | feature-ratio | regions | sequence-filter | beyond |
          front-ends | codes | all
    Every method runs with its default front end (rows L2-normalised; SeqSLAM none) unless --delta.
    Each writes results.csv, results.json and PNG plots into OUT/NAME/; `btel report` turns the
    latest runs into docs/results.md.
    """
    from ..experiments import EXPERIMENTS, describe_row, run_experiment

    names = list(EXPERIMENTS) if name == "all" else [name]
    for n in names:
        click.echo(f"experiment {n}{' (quick)' if quick else ''} …")
        run = run_experiment(n, data_root=data_root, out_dir=out_dir, cache_dir=cache_dir, quick=quick,
                             command=_command_line(), front_end={"delta": delta} if delta else None)
        for row in run.rows:
            click.echo("  " + describe_row(row))
        click.echo(f"  written to {run.out_dir}")


@main.command()
@click.option("--runs", "runs_dir", type=click.Path(file_okay=False), default="runs/experiments", show_default=True)
@click.option("--docs", "docs_dir", type=click.Path(file_okay=False), default="docs", show_default=True)
def report(runs_dir: str, docs_dir: str) -> None:
    """Write docs/results.md and docs/results.json (plus figures) from the latest experiment runs."""
    from ..report import write_report

    path = write_report(runs_dir, docs_dir)
    click.echo(f"written {path} and {path.with_suffix('.json')}")


def _split(methods: str) -> list[str]:
    names = [m.strip() for m in methods.split(",") if m.strip()]
    if not names:
        raise click.UsageError("--methods is empty; give at least one method name (see `btel methods`).")
    return names




def _int(value: str, flag: str) -> int:
    try:
        return int(value)
    except ValueError:
        raise click.UsageError(f"{flag} must be an integer or 'auto'; got {value!r}.") from None


def _command_line() -> str:
    return shlex.join(["btel", *sys.argv[1:]])


from ._gallery import show_cmd  # btel show RUN: the match gallery of a finished run

main.add_command(show_cmd)

if __name__ == "__main__":  # pragma: no cover
    main()
