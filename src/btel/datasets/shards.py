"""Maps stored as a folder of descriptor shards, read without holding them in memory.

A large map is often written in pieces: ``shard_0.npy``, ``shard_1.npy``, … each an ``(n_i, d)``
matrix, rows in route order, shards in natural file-name order (``shard_2`` before ``shard_10``).
:func:`load_shards` returns them as **one ordinary read-only ndarray** backed by a memory-mapped
file, so every part of btel (fancy indexing, chunked statistics, liblinear's column blocks) works
on it unchanged and only the pages being read occupy memory:

- one shard: that file itself, memory-mapped (no copy when it is float32 and C-ordered);
- several shards: their rows are copied, shard by shard and in chunks, into one float32 file
  that is then memory-mapped read-only. This costs one sequential write of N·d·4 bytes of disk
  (1 GB at N = 10⁶, d = 256) and a chunk of RAM at a time. A lazily concatenated view object
  would avoid the copy but would not be an ndarray, and every consumer (scikit-learn included)
  would need to handle it; the one-off copy is the simple, honest choice.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

import numpy as np

from ..exceptions import DataNotFoundError, DimensionMismatchError, InvalidDescriptorsError, ResourceLimitError
from .traverses import IMAGE_EXTENSIONS, natural_key

__all__ = ["list_shards", "load_shards"]

_CHUNK_ROWS = 65536


#: Array files a shard folder must not hold beside its .npy shards (they would be skipped silently).
_OTHER_ARRAY_FILES = (".npz", ".h5", ".hdf5", ".mat", ".pt", ".pth")


def list_shards(folder: str | os.PathLike) -> list[Path]:
    """The ``.npy`` shards in ``folder``, in natural file-name order (hidden files skipped).

    Raises
    ------
    DataNotFoundError
        ``folder`` is not a folder or holds no ``.npy`` file; or one of its ``.npy`` entries is not a
        readable file (a folder, a broken link, a device), or it holds another array file (``.npz``,
        ``.h5``, …): skipped, it would shift the place index of every later row.
    """
    root = Path(folder)
    if not root.is_dir():
        raise DataNotFoundError(f"shard folder {str(root)!r} does not exist or is not a folder.")
    entries = [p for p in root.iterdir() if not p.name.startswith(".")]
    # A shard that cannot be read, skipped, would shift the place index of every row after it: refused.
    for p in entries:
        suffix = p.suffix.lower()
        if suffix == ".npy" and not p.is_file():
            what = ("a folder" if p.is_dir() else "a broken link" if p.is_symlink() and not p.exists()
                    else "not a regular file")
            raise DataNotFoundError(f"shard {p.name!r} in {str(root)!r} is {what}; every .npy entry of a shard "
                                    "folder must be a shard (its rows are places): replace or remove it.")
        if suffix in _OTHER_ARRAY_FILES:
            raise DataNotFoundError(f"{p.name!r} in the shard folder {str(root)!r} is not a .npy shard; a shard "
                                    "folder holds .npy files only (skipping it would shift every later place "
                                    "index): save it with numpy.save, or move it out.")
    shards = sorted((p for p in entries if p.suffix.lower() == ".npy"), key=lambda p: natural_key(p.name))
    if not shards:
        images = sum(1 for p in root.iterdir() if p.is_file() and p.suffix.lower() in IMAGE_EXTENSIONS)
        if images:  # the image folder itself, given where its descriptors go
            raise DataNotFoundError(
                f"{str(root)!r} holds {images} image{'s' * (images != 1)} and no .npy shards: describe them first "
                "(btel.descriptors.extract_descriptors(folder, descriptor), or `btel extract FOLDER -o db.npy`)."
            )
        raise DataNotFoundError(
            f"{str(root)!r} holds no .npy shards; write the map as shard_0.npy, shard_1.npy, … (rows in route order)."
        )
    return shards


def load_shards(
    folder: str | os.PathLike,
    *,
    out: str | os.PathLike | None = None,
    tmp_dir: str | os.PathLike | None = None,
) -> np.ndarray:
    """Read a folder of ``.npy`` descriptor shards as one read-only, memory-mapped (N, d) matrix.

    Parameters
    ----------
    folder : str or path-like
        Folder of ``.npy`` files, each ``(n_i, d)``; rows in route order within a shard, shards in
        natural file-name order. Every shard is checked like :func:`btel.descriptors.load_descriptor_matrix`
        (numeric, 2-D, finite; never unpickled).
    out : str or path-like, optional
        Several shards only: where to write the concatenated float32 ``.npy`` (kept, and usable
        later with ``load_descriptor_matrix(out, mmap_mode="r")``). By default a temporary file in
        ``tmp_dir`` is used and unlinked as soon as it is mapped: on POSIX systems its space is
        freed when the returned array is garbage-collected (elsewhere it stays in ``tmp_dir``).
    tmp_dir : str or path-like, optional
        Folder for the temporary file (default: the system's temporary folder).

    Returns
    -------
    X : ndarray of shape (N, d), float32, read-only
        ``N = Σ n_i``. A ``numpy.memmap``: pages are read from disk when used.

    Raises
    ------
    DataNotFoundError
        The folder does not exist or holds no ``.npy`` file.
    DimensionMismatchError
        Shards with different numbers of columns.
    InvalidDescriptorsError
        A shard that is not a valid descriptor matrix (names the shard).
    """
    # Imported here: btel.descriptors pulls in OpenCV, which btel.datasets does not otherwise need.
    from ..descriptors.npy import load_descriptor_matrix  # names a cut-short shard or a pickle before mapping it

    shards = list_shards(folder)
    if len(shards) == 1:
        return load_descriptor_matrix(shards[0], mmap_mode="r")
    from ..descriptors.npy_header import check_npy_header, npy_header

    # Shapes first, from the headers (the values are checked as they are merged: read once, not twice);
    # a shard whose header is not a numeric matrix's is loaded for its reader to name what it is.
    shapes = []
    for path in shards:
        check_npy_header(path, "shard")
        found = npy_header(path)
        if found is not None and len(found[0]) == 2 and found[1].kind in "fiu":
            shapes.append(found[0])
            continue
        part = load_descriptor_matrix(path, mmap_mode="r")  # one map open at a time: `ulimit -n` stays unhit
        shapes.append(part.shape)
        del part
    d = shapes[0][1]
    for path, shape in zip(shards, shapes):
        if shape[1] != d:
            raise DimensionMismatchError(
                f"shard {path.name} has {shape[1]} columns but {shards[0].name} has {d}; "
                "every shard must hold descriptors of the same dimension."
            )
    n = sum(shape[0] for shape in shapes)
    _check_room(Path(out).parent if out is not None else Path(tmp_dir or tempfile.gettempdir()), n, d, len(shards))
    if out is not None:
        target = Path(out)
        target.parent.mkdir(parents=True, exist_ok=True)
        temporary = False
    else:
        handle, name = tempfile.mkstemp(prefix="btel-shards-", suffix=".npy", dir=tmp_dir)
        os.close(handle)
        target = Path(name)
        temporary = True
    try:
        merged = np.lib.format.open_memmap(target, mode="w+", dtype=np.float32, shape=(n, d))
        row = 0
        for path, shape in zip(shards, shapes):
            part = load_descriptor_matrix(path, mmap_mode="r")
            if part.shape != shape:
                raise InvalidDescriptorsError(f"shard {path.name} changed while it was being read.")
            for start in range(0, part.shape[0], _CHUNK_ROWS):
                block = part[start : start + _CHUNK_ROWS]
                merged[row : row + block.shape[0]] = block
                row += block.shape[0]
                del block  # a view keeps the shard's map (and its file descriptor) open
            del part
        merged.flush()
        del merged
        X = np.load(target, mmap_mode="r", allow_pickle=False)
    except BaseException:
        if temporary:
            target.unlink(missing_ok=True)
        raise
    if temporary:
        try:
            target.unlink()  # the mapping keeps the data alive until X is released (POSIX)
        except OSError:  # pragma: no cover - Windows cannot unlink a mapped file
            pass
    return X


def _check_room(folder: Path, n: int, d: int, n_shards: int) -> None:
    """Refuse to merge shards into a folder without room for the (n, d) float32 map (a disk filled up to the
    last byte fails every other program on it too; sparse shards may claim terabytes)."""
    import shutil

    from ..core.limits import format_size

    where = next((p for p in (folder, *folder.parents) if p.exists()), None)
    if where is None:
        return
    need, free = 4 * n * d + 4096, shutil.disk_usage(where).free
    if need > free:
        raise ResourceLimitError(
            f"the {n_shards} shards ({n} rows × {d} values) are merged into one float32 map of {format_size(need)} "
            f"in {str(where)!r}, which has {format_size(free)} free; free space there, set TMPDIR to a folder with "
            "room (or pass out= / tmp_dir= to load_shards), or check that the shards hold the rows they claim.")

