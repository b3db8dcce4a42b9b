"""hloc HDF5 global descriptors, read as untrusted input.

An HDF5 file can point outside itself: a dataset with *external storage* reads its bytes from any
local file, a *virtual dataset* maps other files, and an *external link* opens another file. None
of that is followed here. The reader walks the file's links itself (never following soft or
external links), refuses external storage, virtual datasets and non-numeric dtypes, checks every
declared shape against :mod:`btel.limits` before reading, and turns every h5py error into an
:class:`InvalidDescriptorsError` naming the item.
"""

from __future__ import annotations

import os
import re
from pathlib import Path
from typing import Any

import numpy as np

from .._validation import check_descriptors
from ..exceptions import BTELError, DataNotFoundError, InvalidDescriptorsError
from ..limits import check_count, open_regular

__all__ = ["load_hloc_global", "HLOC_DATASET"]

HLOC_DATASET = "global_descriptor"
_MAX_OBJECTS = 10_000_000  # groups and datasets visited (each costs bytes in the file anyway)


def _natural_key(name: str) -> list:
    return [int(part) if part.isdigit() else part.lower() for part in re.split(r"(\d+)", name)]


def _checked_dataset(ds: Any, item: str, source: str) -> tuple[tuple[int, ...], np.dtype]:
    """Shape and dtype of a dataset that may be read: inside the file, numeric, (d,) or (1, d)."""
    if ds.is_virtual:
        raise InvalidDescriptorsError(f"{source}: {item!r} is a virtual dataset (it maps other files); refused.")
    if ds.external:
        raise InvalidDescriptorsError(
            f"{source}: {item!r} stores its data in external files ({len(ds.external)}); btel reads only data "
            "inside the HDF5 file.")
    dtype = ds.dtype
    if dtype.kind not in "iuf" or dtype.fields is not None or dtype.subdtype is not None:
        raise InvalidDescriptorsError(f"{source}: {item!r} has dtype {dtype}; descriptors must be numbers.")
    shape = tuple(int(s) for s in ds.shape or ())
    if not (len(shape) == 1 or (len(shape) == 2 and shape[0] == 1)) or 0 in shape:
        raise InvalidDescriptorsError(
            f"{source}: {item!r} has shape {shape}; a global descriptor is (d,) or (1, d) with d ≥ 1.")
    return shape, dtype


def load_hloc_global(path: str | os.PathLike, prefix: str | None = None) -> tuple[np.ndarray, list[str]]:
    """Global descriptors from an hloc HDF5 feature file, one row per image in natural name order.

    Parameters
    ----------
    path : path
        HDF5 file with one group per image name, each holding a ``global_descriptor`` dataset
        (shape (d,) or (1, d), a numeric dtype, stored inside the file).
    prefix : str, optional
        Keep only images whose name starts with this (e.g. ``"db/"``).

    Returns
    -------
    X : ndarray of shape (n_images, d), dtype float32
    names : list of str
        Image name of each row.

    Raises
    ------
    DataNotFoundError
        Missing file, not a regular file, or no ``global_descriptor`` (under ``prefix``).
    InvalidDescriptorsError
        Not an HDF5 file, external storage, virtual datasets, soft or external links, non-numeric
        dtypes, descriptors of different lengths, non-finite values, or any other h5py error.
    ResourceLimitError
        The declared shapes exceed :mod:`btel.limits` (raise ``BTEL_MEMORY_LIMIT``).
    """
    import h5py

    path = Path(path)
    if not path.exists():
        raise DataNotFoundError(f"descriptor file {str(path)!r} does not exist. Check the path.")
    with open_regular(path):
        pass
    source = repr(str(path))
    item = "/"
    try:
        with h5py.File(path, "r") as fh:
            selected: dict[str, Any] = {}
            stack: list[tuple[str, Any]] = [("", fh)]
            visited = 0
            while stack:
                base, group = stack.pop()
                for key in group.keys():
                    item = f"{base}{key}"
                    visited += 1
                    if visited > _MAX_OBJECTS:
                        raise InvalidDescriptorsError(f"{source}: more than {_MAX_OBJECTS} objects; not hloc features.")
                    link = group.get(key, getlink=True)
                    if isinstance(link, (h5py.SoftLink, h5py.ExternalLink)):
                        kind = "an external link" if isinstance(link, h5py.ExternalLink) else "a soft link"
                        raise InvalidDescriptorsError(
                            f"{source}: {item!r} is {kind}; btel follows no links (hloc files have none).")
                    obj = group[key]
                    if isinstance(obj, h5py.Group):
                        stack.append((item + "/", obj))
                    elif isinstance(obj, h5py.Dataset) and key == HLOC_DATASET:
                        image = base[:-1]
                        if prefix is None or image.startswith(prefix):
                            selected[image] = obj
            shapes = {image: _checked_dataset(ds, f"{image}/{HLOC_DATASET}", source)
                      for image, ds in selected.items()}
            total = sum(int(np.prod(shape)) for shape, _ in shapes.values())
            check_count(total, 4 + max([d.itemsize for _, d in shapes.values()], default=0),
                        f"HDF5 descriptors in {source} ({len(shapes)} images)")
            found: dict[str, np.ndarray] = {}
            for image, ds in selected.items():
                item = f"{image}/{HLOC_DATASET}"
                found[image] = np.asarray(ds[()]).reshape(-1)
                if found[image].size != int(np.prod(shapes[image][0])):
                    raise InvalidDescriptorsError(f"{source}: {item!r} did not hold its declared shape.")
    except BTELError:
        raise
    except Exception as exc:  # h5py raises OSError, RuntimeError, KeyError, TypeError, ValueError…
        what = "is not a readable HDF5 file" if item == "/" else f"item {item!r} could not be read"
        raise InvalidDescriptorsError(f"{source} {what} ({type(exc).__name__}: {str(exc)[:200]}).") from None
    if not found:
        where = f" under {prefix!r}" if prefix else ""
        raise DataNotFoundError(
            f"{source} holds no '{HLOC_DATASET}' dataset{where}; expected hloc global features (one group "
            "per image name with a global_descriptor). Local features (keypoints/descriptors) are not global "
            "descriptors.")
    names = sorted(found, key=_natural_key)
    lengths = {found[n].size for n in names}
    if len(lengths) != 1:
        raise InvalidDescriptorsError(
            f"{source}: the global descriptors have different lengths ({sorted(lengths)[:5]}); one model must "
            "describe every image.")
    X = np.stack([found[n] for n in names])
    return check_descriptors(X, name=f"global descriptors in {path.name}"), names
