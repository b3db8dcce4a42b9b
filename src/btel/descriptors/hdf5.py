"""hloc HDF5 global descriptors, read as untrusted input.

An HDF5 file can point outside itself: a dataset with *external storage* reads its bytes from any
local file, a *virtual dataset* maps other files, and an *external link* opens another file. None
of that is followed here. The reader walks the file's links itself (never following soft or
external links) and enters every object once: a group linked from inside itself (a cycle) or from
two places is refused by name, since hloc files are trees. It refuses external storage, virtual
datasets and non-numeric dtypes, and checks every declared shape against :mod:`btel.core.limits`
before reading. Chunks are bounded twice, because HDF5 inflates a whole chunk to read one value
of it and inflates as far as the stored stream goes, whatever the chunk declares: the declared
chunk must fit the limit, and so must what each stored chunk can inflate to (gzip, shuffle and
fletcher32 are the only filters read; their output is bounded by the bytes stored). Every h5py
error becomes an :class:`InvalidDescriptorsError` naming the item.
"""

from __future__ import annotations

import math
import os
import re
from pathlib import Path
from typing import Any

import numpy as np

from ..core.validation import check_descriptors
from ..exceptions import BTELError, DataNotFoundError, InvalidDescriptorsError
from ..core.limits import check_count, open_regular

__all__ = ["load_hloc_global", "HLOC_DATASET"]

HLOC_DATASET = "global_descriptor"
_MAX_OBJECTS = 10_000_000  # links looked at (each costs bytes in the file anyway)
_MAX_DEPTH = 64  # nested groups (hloc nests one group per "/" of an image name)
#: Filters read (HDF5 filter id → name): their output is bounded by the bytes a chunk stores. Others
#: (szip, n-bit, scale-offset, LZF, plugins) size their output from parameters the file states.
_FILTERS = {1: "gzip", 2: "shuffle", 3: "fletcher32"}
#: Bytes of memory per stored byte of a gzip chunk: deflate inflates at most 1032:1, and HDF5 grows
#: its output buffer by doubling.
_GZIP_GROWTH = 2 * 1032
_MAX_CHUNKS = 65_536  # per dataset (a global descriptor needs one)


def _natural_key(name: str) -> tuple:
    # Digit runs by value (img2 < img10); names equal as numbers (img1, img01) by the name itself.
    return [int(part) if part.isdigit() else part.lower() for part in re.split(r"(\d+)", name)], name


def _shown(item: str) -> str:
    """An item name for a message: quoted with control characters escaped, at most 120 characters."""
    return repr(item if len(item) <= 120 else item[:117] + "...")


def _checked_dataset(ds: Any, item: str, source: str) -> tuple[tuple[int, ...], np.dtype]:
    """Shape and dtype of a dataset that may be read: inside the file, numeric, (d,) or (1, d),
    HDF5's own filters only, and every chunk's decompressed size within the memory limit."""
    name = f"{source}: {_shown(item)}"
    if ds.is_virtual:
        raise InvalidDescriptorsError(f"{name} is a virtual dataset (it maps other files); refused.")
    if ds.external:
        raise InvalidDescriptorsError(f"{name} stores its data in external files ({len(ds.external)}); btel "
                                      "reads only data inside the HDF5 file.")
    dtype = ds.dtype
    if dtype.kind not in "iuf" or dtype.fields is not None or dtype.subdtype is not None:
        raise InvalidDescriptorsError(f"{name} has dtype {dtype}; descriptors must be numbers.")
    shape = tuple(int(s) for s in ds.shape or ())
    if not (len(shape) == 1 or (len(shape) == 2 and shape[0] == 1)) or 0 in shape:
        raise InvalidDescriptorsError(
            f"{name} has shape {shape}; a global descriptor is (d,) or (1, d) with d ≥ 1.")
    plist = ds.id.get_create_plist()
    codes = [int(plist.get_filter(index)[0]) for index in range(plist.get_nfilters())]
    for code in codes:
        if code not in _FILTERS:
            raise InvalidDescriptorsError(
                f"{name} is encoded with HDF5 filter {code}; btel reads gzip, shuffle and fletcher32 only "
                "(the others size their output from the file's own parameters). Re-save it with gzip or "
                "none.")
    if ds.chunks is not None:
        chunk = tuple(int(c) for c in ds.chunks)
        check_count(math.prod(chunk), dtype.itemsize,
                    f"{name} (one chunk of shape {chunk}, decompressed whole to read it)")
        n_chunks = math.prod(-(-n // c) for n, c in zip(shape, chunk))
        if n_chunks > _MAX_CHUNKS:
            raise InvalidDescriptorsError(f"{name} is split into {n_chunks} chunks; a global descriptor "
                                          f"needs a few (at most {_MAX_CHUNKS} are read).")
        growth = _GZIP_GROWTH if 1 in codes else 1
        stored = max(_stored_chunk_sizes(ds), default=0)
        check_count(stored, growth,
                    f"{name} (a chunk of {stored} stored bytes{', gzip-inflated' if growth > 1 else ''})")
    return shape, dtype


def _stored_chunk_sizes(ds: Any) -> list[int]:
    """Bytes each chunk of ``ds`` stores in the file (read from the chunk index, not the chunks)."""
    sizes: list[int] = []
    if hasattr(ds.id, "chunk_iter"):
        ds.id.chunk_iter(lambda info: sizes.append(int(info.size)))
    else:  # pragma: no cover - h5py built on HDF5 < 1.12.3
        sizes = [int(ds.id.get_chunk_info(i).size) for i in range(ds.id.get_num_chunks())]
    return sizes


def _walk(fh: Any, prefix: str | None, source: str, where: list[str]) -> dict[str, Any]:
    """The ``global_descriptor`` datasets of the images under ``prefix``: image name → dataset.

    Each link is looked at once and each object entered once, so the walk takes at most as many
    steps as the file has links: a soft or external link, a second hard link to an object already
    reached (``g["loop"] = g``, or one group under two names), more than :data:`_MAX_OBJECTS`
    links and groups nested deeper than :data:`_MAX_DEPTH` are refused by name. ``where[0]`` is
    kept at the item being read, for the caller's message when h5py fails.
    """
    import h5py

    selected: dict[str, Any] = {}
    # Only objects with more than one hard link can be reached twice: only they are remembered, and
    # groups wait on the stack by name, not as open objects (a file of 10⁶ empty groups held 2 GB).
    seen: dict[tuple[Any, int], str] = {_identity(fh): "/"}
    stack: list[tuple[str, int]] = [("", 0)]
    visited = 0
    while stack:
        base, depth = stack.pop()
        group = fh[base] if base else fh
        for key in group.keys():
            item = where[0] = f"{base}{key}"
            visited += 1
            if visited > _MAX_OBJECTS:
                raise InvalidDescriptorsError(
                    f"{source}: more than {_MAX_OBJECTS} objects; not hloc features.")
            link = group.get(key, getlink=True)
            if isinstance(link, (h5py.SoftLink, h5py.ExternalLink)):
                kind = "an external link" if isinstance(link, h5py.ExternalLink) else "a soft link"
                raise InvalidDescriptorsError(
                    f"{source}: {_shown(item)} is {kind}; btel follows no links (hloc files have none).")
            obj = group[key]
            info = h5py.h5o.get_info(obj.id)
            identity = (obj.id.fileno, int(info.addr))
            if identity in seen:
                first = seen[identity]
                cycle = " (a link cycle)" if first == "/" or item.startswith(first + "/") else ""
                raise InvalidDescriptorsError(
                    f"{source}: {_shown(item)} links to {_shown(first)}, already reached{cycle}; hloc files "
                    "are trees, every group and dataset under one name.")
            if info.rc > 1:
                seen[identity] = item
            if isinstance(obj, h5py.Group):
                if depth >= _MAX_DEPTH:
                    raise InvalidDescriptorsError(
                        f"{source}: {_shown(item)} nests groups more than {_MAX_DEPTH} deep; not hloc "
                        "features.")
                stack.append((item + "/", depth + 1))
            elif isinstance(obj, h5py.Dataset) and key == HLOC_DATASET:
                image = base[:-1]
                if prefix is None or image.startswith(prefix):
                    selected[image] = obj
    return selected


def _identity(obj: Any) -> tuple[Any, int]:
    """(file number, object address): equal for two names of one HDF5 object."""
    import h5py

    return obj.id.fileno, int(h5py.h5o.get_info(obj.id).addr)


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
        Not an HDF5 file, external storage, virtual datasets, soft or external links, link cycles
        or objects under two names, filters other than gzip/shuffle/fletcher32, non-numeric
        dtypes, descriptors of different lengths, non-finite values, or any other h5py error.
    ResourceLimitError
        The declared shapes, one chunk's declared size, or what one stored chunk can inflate to
        exceed :mod:`btel.core.limits` (raise ``BTEL_MEMORY_LIMIT``).
    """
    import h5py

    path = Path(path)
    if not path.exists():
        raise DataNotFoundError(f"descriptor file {str(path)!r} does not exist. Check the path.")
    with open_regular(path):
        pass
    source = repr(str(path))
    where = ["/"]
    try:
        with h5py.File(path, "r") as fh:
            selected = _walk(fh, prefix, source, where)
            shapes = {}
            for image, ds in selected.items():
                where[0] = f"{image}/{HLOC_DATASET}"
                shapes[image] = _checked_dataset(ds, where[0], source)
            total = sum(int(np.prod(shape)) for shape, _ in shapes.values())
            check_count(total, 4 + max([d.itemsize for _, d in shapes.values()], default=0),
                        f"HDF5 descriptors in {source} ({len(shapes)} images)")
            found: dict[str, np.ndarray] = {}
            for image, ds in selected.items():
                where[0] = f"{image}/{HLOC_DATASET}"
                found[image] = np.asarray(ds[()]).reshape(-1)
                if found[image].size != int(np.prod(shapes[image][0])):
                    raise InvalidDescriptorsError(
                        f"{source}: {_shown(where[0])} did not hold its declared shape.")
    except BTELError:
        raise
    except Exception as exc:  # h5py raises OSError, RuntimeError, KeyError, TypeError, ValueError…
        what = ("is not a readable HDF5 file" if where[0] == "/" else
                f"item {_shown(where[0])} could not be read")
        raise InvalidDescriptorsError(f"{source} {what} ({type(exc).__name__}: {str(exc)[:200]}).") from None
    if not found:
        where_text = f" under {prefix!r}" if prefix else ""
        raise DataNotFoundError(
            f"{source} holds no '{HLOC_DATASET}' dataset{where_text}; expected hloc global features (one "
            "group per image name with a global_descriptor). Local features (keypoints/descriptors) are not "
            "global descriptors.")
    names = sorted(found, key=_natural_key)
    lengths = {found[n].size for n in names}
    if len(lengths) != 1:
        raise InvalidDescriptorsError(
            f"{source}: the global descriptors have different lengths ({sorted(lengths)[:5]}); one model must "
            "describe every image.")
    X = np.stack([found[n] for n in names])
    return check_descriptors(X, name=f"global descriptors in {path.name}"), names
