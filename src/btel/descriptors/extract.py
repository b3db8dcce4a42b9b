"""One call from images to a descriptor matrix: what ``btel extract`` wraps."""

from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path
from typing import Any

import numpy as np

from ..core.claims import atomic_output
from ..core.fingerprint import file_record
from ..core.validation import check_is_fitted
from ..exceptions import InvalidParameterError, NotFittedError
from .base import ImageDescriptor, get_descriptor, registered
from .images import ImageInput
from .npy_header import read_sidecar

__all__ = ["extract_descriptors"]


def _resolve(descriptor: Any) -> ImageDescriptor:
    if isinstance(descriptor, ImageDescriptor):
        return descriptor
    if isinstance(descriptor, str) and descriptor.lower().replace("-", "").replace("_", "") in registered():
        return get_descriptor(descriptor)
    if isinstance(descriptor, (str, os.PathLike)) and Path(descriptor).is_file():
        return ImageDescriptor.load(descriptor)
    raise InvalidParameterError(
        f"descriptor must be a name ({', '.join(sorted(registered()))}), a saved descriptor file, or an "
        f"ImageDescriptor; got {descriptor!r}."
    )


def _same_source(a: Any, b: Any) -> bool:
    if a is b:
        return True
    if isinstance(a, (str, os.PathLike)) and isinstance(b, (str, os.PathLike)):
        return Path(a).resolve() == Path(b).resolve()
    return False


def extract_descriptors(
    images: ImageInput,
    descriptor: str | os.PathLike | ImageDescriptor = "hog",
    *,
    fit_on: ImageInput | None = None,
    progress: bool = True,
) -> np.ndarray:
    """Describe images with one of btel's front ends.

    Parameters
    ----------
    images : folder, sequence of image paths or arrays
        The images to describe, in route order (a folder is read in natural file-name order).
    descriptor : str, path-like or ImageDescriptor
        A registry name (``"hog"``, ``"patchnorm"``, ``"densevlad"``) with default parameters, a
        file written by :meth:`ImageDescriptor.save` (e.g. the map's DenseVLAD vocabulary), or a
        descriptor object. An object passed here is fitted in place when ``fit_on`` is given, so
        it can be saved afterwards for the queries.
    fit_on : folder, sequence of image paths or arrays, optional
        Map images to learn from (DenseVLAD's vocabulary and PCA). It may be the same folder as
        ``images`` (then the work is shared). Never fit on query images: map and queries must be
        described by the same fitted descriptor.
    progress : bool
        Show progress bars (only on a terminal).

    Returns
    -------
    X : ndarray of shape (n_images, dim), dtype float32

    Raises
    ------
    NotFittedError
        A descriptor that learns state, with neither ``fit_on`` nor a fitted/loaded descriptor.
    InvalidParameterError
        An unknown descriptor name or bad parameter.
    DataNotFoundError
        A missing folder, a folder without images, or an unreadable image file.
    """
    model = _resolve(descriptor)
    if fit_on is not None:
        if _same_source(fit_on, images):
            return model.fit_transform(images, progress=progress)
        model.fit(fit_on, progress=progress)
    elif model.requires_fit:
        try:
            check_is_fitted(model, "dim_")
        except NotFittedError:
            raise NotFittedError(
                f"descriptor {model.name!r} learns from map images: pass fit_on=<map images> (they may be the "
                "same as the images to describe), or a descriptor fitted on the map / loaded from its file."
            ) from None
    return model.transform(images, progress=progress)


def extraction_key(paths: list[Path], model: ImageDescriptor, fit_on: Any = None) -> dict[str, Any]:
    """What determines an extraction's output: the images (name, size, mtime), the descriptor and
    its parameters, and what it was fitted on — the fit-on images (name, size, mtime), or the
    fitted arrays of a descriptor loaded from its file (a SHA-1). Two extractions with equal keys
    give equal matrices."""
    from .images import list_images

    params = {k: (list(v) if isinstance(v, tuple) else v) for k, v in model.get_params().items()}
    prefitted = bool(getattr(model, "dim_", None)) and bool(getattr(model, "requires_fit", False))
    parents = {p.parent for p in paths}
    key = {
        "descriptor": type(model).__name__,
        "params": json.loads(json.dumps(params, default=str)),
        "fit_on": str(Path(fit_on).resolve()) if isinstance(fit_on, (str, os.PathLike)) else None,
        "prefitted": prefitted,
        "images": _file_stamps(paths),
        # Where the images are, so that a run can show them (btel evaluate's match gallery).
        "folder": str(parents.pop().resolve()) if len(parents) == 1 else None,
    }
    # The path alone would vouch for a fit-on folder whose images changed, or a descriptor file
    # fitted again on another map: the images and the fitted arrays themselves are recorded.
    if isinstance(fit_on, (str, os.PathLike)) and Path(fit_on).is_dir():
        key["fit_on_images"] = _file_stamps(list_images(fit_on))
    elif isinstance(fit_on, (list, tuple)):
        key["fit_on_images"] = _file_stamps([Path(p) for p in fit_on])
    if prefitted:
        digest = hashlib.sha1()
        for name, array in sorted(model._stored_arrays().items()):
            digest.update(name.encode() + np.ascontiguousarray(array).tobytes())
        key["fitted_sha1"] = digest.hexdigest()
    return key


def _file_stamps(paths: list[Path]) -> list[list[Any]]:
    """``[name, size, mtime in ns]`` of each file: what says a file is the one an extraction read."""
    return [[p.name, p.stat().st_size, int(p.stat().st_mtime_ns)] for p in paths]


def same_extraction(cached: Any, key: dict[str, Any]) -> bool:
    """The sidecar ``cached`` records the extraction ``key``; a sidecar written before the image
    folder was recorded (no ``"folder"``) still matches on everything else. The record's ``"output"``
    (the matrix file it vouches for) is checked by :func:`output_unchanged`."""
    if not isinstance(cached, dict):
        return False
    cached = {k: v for k, v in cached.items() if k != "output"}
    if "folder" not in cached:
        return cached == {k: v for k, v in key.items() if k != "folder"}
    return cached == key


def output_unchanged(cached: Any, output: str | os.PathLike) -> bool:
    """The matrix file holds the bytes its record was written for (a record from before btel kept them:
    True). A file replaced by other data of the same shape, or truncated, is then no cache of anything."""
    recorded = cached.get("output") if isinstance(cached, dict) else None
    if not isinstance(recorded, dict):
        return True
    try:
        return Path(output).stat().st_size == recorded.get("bytes") and file_record(Path(output)) == recorded
    except OSError:
        return False


def extract_cached(
    images: str | os.PathLike | list[Path],
    output: str | os.PathLike,
    descriptor: str | os.PathLike | ImageDescriptor = "hog",
    *,
    fit_on: Any = None,
    progress: bool = True,
    force: bool = False,
    overwrite: bool = True,
) -> tuple[np.ndarray, bool]:
    """:func:`extract_descriptors` into ``output`` (.npy), reusing it when nothing changed.

    A JSON file beside ``output`` (``output + ".json"``) records :func:`extraction_key`; when it
    matches, the stored matrix is loaded instead of recomputed. Writing is atomic (a temporary
    file, then a rename; :func:`btel.core.claims.atomic_output`), so an interrupted run or a full disk
    never leaves a partial matrix or a temporary behind. With ``overwrite=False`` a matrix that
    appeared at ``output`` during the extraction (another process's) is kept:
    :class:`~btel.exceptions.OutputExistsError`.

    Returns
    -------
    X : ndarray of shape (n_images, dim), float32
    reused : bool
        True when the cached matrix was used.
    """
    from .images import list_images

    paths = list_images(images) if isinstance(images, (str, os.PathLike)) else [Path(p) for p in images]
    model = _resolve(descriptor)
    key = extraction_key(paths, model, fit_on)
    output = Path(output)
    sidecar = Path(str(output) + ".json")
    refuse_foreign_record(output, overwrite)
    if not force and output.is_file():
        cached = read_sidecar(output)  # an unreadable record is refused (read_sidecar), not recomputed over
        if same_extraction(cached, key) and output_unchanged(cached, output):
            if "output" not in cached or "folder" not in cached:  # an older record: complete it now
                with atomic_output(sidecar, text=True) as fh:
                    fh.write(json.dumps({**key, "output": file_record(output)}, indent=1))
            from ..exceptions import BTELError
            from .npy import load_descriptor_matrix

            try:
                return load_descriptor_matrix(output), True  # checked like any input: the file may have changed
            except (BTELError, OSError, ValueError):  # damaged since (truncated…): extracted again below
                pass
    X = extract_descriptors(paths, model, fit_on=fit_on, progress=progress)
    output.parent.mkdir(parents=True, exist_ok=True)
    # Unique temporaries: two runs filling the same cache at once (two experiments started together)
    # each write their own; the matrix is published first, then the key that vouches for it.
    with atomic_output(output, overwrite=overwrite) as fh:
        np.save(fh, X)
    with atomic_output(sidecar, text=True) as fh:
        fh.write(json.dumps({**key, "output": file_record(output)}, indent=1))
    return X, False


def _is_record(cached: Any) -> bool:
    """A JSON value that ``btel extract`` wrote beside a matrix (:func:`extraction_key`'s keys)."""
    return isinstance(cached, dict) and {"descriptor", "images"} <= cached.keys()


def refuse_foreign_record(output: str | os.PathLike, overwrite: bool) -> None:
    """Refuse to write ``output``'s record (``output + ".json"``) over a file that is not one.

    An extraction writes its record beside the matrix; a file of the user's at that path (notes, another
    tool's JSON) would be replaced without a word. Without ``overwrite`` anything there but a regular file
    holding a record of btel's is refused (a link too: writing would replace the link); a folder or special
    file there always is (by :func:`read_sidecar`, which names it): a record cannot replace it, and finding
    out after the matrix was written left the matrix behind.

    Raises
    ------
    OutputExistsError, InvalidDescriptorsError
    """
    from ..exceptions import BTELError, OutputExistsError

    sidecar = Path(str(output) + ".json")
    if not os.path.lexists(sidecar):
        return
    link = sidecar.is_symlink()
    try:
        cached = read_sidecar(output)
    except BTELError:
        if link or not sidecar.is_file():
            raise
        cached = None  # a regular file btel cannot read as a record: the user's
    if overwrite or (_is_record(cached) and not link):
        return
    what = "a link, which writing would replace" if link else "a file that is not btel extract's record of a matrix"
    raise OutputExistsError(
        f"{str(sidecar)!r} is {what}; extracting to {str(output)!r} writes the record of its images there. "
        "Move it away, give another -o, or --overwrite to replace it.")


def written_by_extract(output: str | os.PathLike) -> bool:
    """True when ``output`` is a matrix that ``btel extract`` wrote (its record beside it vouches for its bytes):
    replacing it loses nothing of the user's."""
    from ..exceptions import BTELError

    try:
        cached = read_sidecar(output)
        return Path(output).is_file() and _is_record(cached) and output_unchanged(cached, output)
    except (BTELError, OSError):
        return False


def is_extraction_of(output: str | os.PathLike, images: str | os.PathLike, model: ImageDescriptor,
                     fit_on: Any = None) -> bool:
    """True when ``output`` was written by an extraction of these images with this descriptor (its JSON
    sidecar says so): reusing or recomputing it replaces nothing of the user's."""
    from .images import list_images

    cached = read_sidecar(output)  # outside the try: an unreadable record is refused, not taken for "no"
    try:
        return (cached is not None and same_extraction(cached, extraction_key(list_images(images), model, fit_on))
                and output_unchanged(cached, output))
    except (OSError, ValueError):
        return False


def extraction_difference(output: str | os.PathLike, images: str | os.PathLike, model: ImageDescriptor,
                          fit_on: Any = None) -> str | None:
    """What differs between the extraction ``output``'s JSON sidecar records and this one, in words;
    None when there is no sidecar or it names another image folder (``output`` is then no cache of
    these images) or nothing differs."""
    from .images import list_images

    cached = read_sidecar(output)
    if cached is None:
        return None
    key = extraction_key(list_images(images), model, fit_on)
    if not isinstance(cached, dict) or cached.get("folder") not in (None, key["folder"]):
        return None
    old = {entry[0]: entry[1:] for entry in cached.get("images", []) if isinstance(entry, list) and entry}
    new = {entry[0]: entry[1:] for entry in key["images"]}
    parts = []
    for what, names in (("changed", sorted(n for n in new.keys() & old.keys() if new[n] != old[n])),
                        ("added", sorted(new.keys() - old.keys())), ("removed", sorted(old.keys() - new.keys()))):
        if names:
            parts.append(f"{len(names)} image{'s' * (len(names) != 1)} {what} (e.g. {names[0]})")
    if cached.get("descriptor") != key["descriptor"]:
        parts.append(f"the descriptor ({cached.get('descriptor')} → {key['descriptor']})")
    elif cached.get("params") != key["params"] and isinstance(cached.get("params"), dict):
        parts += [f"{k}: {cached['params'].get(k)} → {v}" for k, v in key["params"].items()
                  if cached["params"].get(k) != v][:3]
    if (cached.get("fit_on"), cached.get("fit_on_images")) != (key["fit_on"], key.get("fit_on_images")):
        parts.append("the images it was fitted on")
    if cached.get("fitted_sha1") != key.get("fitted_sha1"):
        parts.append("the descriptor file's fitted arrays")
    if not output_unchanged(cached, output):
        parts.append(f"{Path(output).name} itself (other bytes than the extraction wrote)")
    return "; ".join(parts) or None


def extract_delta_cached(images: str | os.PathLike, output: str | os.PathLike, model: ImageDescriptor,
                         window: int, *, fit_on: Any = None, progress: bool = True, force: bool = False,
                         overwrite: bool = False) -> tuple[np.ndarray, np.ndarray, Path]:
    """Delta descriptors over ``window`` frames into ``output`` (.npy); the plain descriptors they come
    from are cached beside it (``<stem>.plain.npy``, :func:`btel.descriptors.extract.extract_cached`).

    Returns
    -------
    D : ndarray of shape (n_images, dim), float32
        What ``output`` holds (:func:`btel.core.frontend.delta_descriptors`).
    X : ndarray of shape (n_images, dim), float32
        The plain descriptors.
    plain : Path
        Where they are cached.
    """
    from ..core.frontend import delta_descriptors
    from ..exceptions import OutputExistsError

    output = Path(output)
    plain = output.with_name(output.stem + ".plain.npy")
    ours = written_by_extract(plain)  # btel's own cache of the plain descriptors: reused or replaced freely
    if os.path.lexists(plain) and not ours and not overwrite:
        raise OutputExistsError(
            f"{str(plain)!r} exists without btel extract's record of it beside it ({plain.name}.json), so it may "
            f"be another program's; extracting to {str(output)!r} with --delta keeps the plain descriptors there. "
            "Move it away, give another -o, or --overwrite to replace it.")
    X, _ = extract_cached(images, plain, model, fit_on=fit_on, progress=progress, force=force,
                          overwrite=overwrite or ours)
    D = delta_descriptors(X, window)
    output.parent.mkdir(parents=True, exist_ok=True)
    with atomic_output(output, overwrite=overwrite) as fh:  # whole or not at all; a racing file is kept
        np.save(fh, D)
    return D, X, plain
