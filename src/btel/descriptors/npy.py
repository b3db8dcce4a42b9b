"""Descriptor matrices computed by other tools (NetVLAD, DenseVLAD in MATLAB, hloc, ...).

Row i is the global descriptor of image (place) i. Formats:

- ``.npy`` / ``.npz``, read with ``allow_pickle=False``: nothing in a descriptor file can run code;
- ``.h5`` / ``.hdf5`` as written by hloc's ``extract_features`` for global descriptors (NetVLAD,
  OpenIBL, EigenPlaces, ...): one HDF5 group per image name holding a ``global_descriptor``
  dataset. Image names may contain ``/`` (hloc then nests groups: ``db/0001.jpg``). Rows are the
  images in **natural name order** (``img2`` before ``img10``), which is the route order when the
  file names are frame numbers; ``PATH.h5:PREFIX`` keeps only the names starting with ``PREFIX``
  (hloc often keeps map and query images in one file, e.g. ``feats.h5:db/`` and ``feats.h5:query/``).
  HDF5 holds plain arrays only; h5py reads no pickles. External storage, virtual datasets, links
  and non-numeric dtypes are refused (see :mod:`btel.descriptors.hdf5`).
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from .._validation import check_descriptors
from ..exceptions import DataNotFoundError, InvalidDescriptorsError, InvalidParameterError
from ..limits import check_numpy_file, open_regular
from .hdf5 import load_hloc_global

__all__ = ["load_descriptor_matrix", "load_hloc_global", "HDF5_SUFFIXES"]

HDF5_SUFFIXES = (".h5", ".hdf5")


def split_prefix(path: str | os.PathLike) -> tuple[Path, str | None]:
    """``"feats.h5:db/"`` → (Path("feats.h5"), "db/"), ``"x.npz:hlrTrain"`` → (Path("x.npz"), "hlrTrain");
    a path that exists as given is kept whole."""
    text = os.fspath(path)
    if Path(text).exists() or ":" not in text:
        return Path(text), None
    head, _, prefix = text.rpartition(":")
    if Path(head).suffix.lower() in (*HDF5_SUFFIXES, ".npz"):
        return Path(head), prefix
    return Path(text), None


def load_descriptor_matrix(
    path: str | os.PathLike, *, mmap_mode: str | None = None, key: str | None = None
) -> np.ndarray:
    """Load and check an ``(n, d)`` descriptor matrix from a ``.npy`` (or ``.npz``) file.

    Parameters
    ----------
    path : str or path-like
        A ``.npy`` file, an ``.npz`` archive (then ``key`` names the array; it may be left
        out when the archive holds exactly one; ``PATH.npz:KEY`` names it too), or an hloc ``.h5`` file (``PATH.h5:PREFIX``
        selects the images whose name starts with PREFIX; see the module docstring).
    mmap_mode : {None, "r", "c"}
        ``"r"`` memory-maps a ``.npy`` read-only instead of reading it into memory, for maps
        larger than RAM; the result stays a view of the file when it is already float32 and
        C-ordered (otherwise it is converted in memory). ``"c"`` is copy-on-write. Writable modes
        are refused: loading must never change the file. Not available for ``.npz``.
    key : str, optional
        Array name inside an ``.npz`` archive.

    Returns
    -------
    X : ndarray of shape (n, d), dtype float32
        Every value finite.

    Raises
    ------
    DataNotFoundError
        The file does not exist (or is a folder), or ``key`` is not in the archive.
    InvalidDescriptorsError
        Not a readable ``.npy``/``.npz``, pickled objects, not 2-D, not numeric, NaN/inf, empty.
    InvalidParameterError
        A writable or unknown ``mmap_mode``, or ``mmap_mode`` with an ``.npz``.
    """
    path, prefix = split_prefix(path)
    if prefix is not None and path.suffix.lower() == ".npz":
        if key is not None and key != prefix:
            raise InvalidParameterError(f"{path}:{prefix} names array {prefix!r} but key={key!r}; give one.")
        key = prefix
    if path.suffix.lower() in HDF5_SUFFIXES:
        if key is not None:
            raise InvalidParameterError(f"key={key!r} only applies to .npz archives; write {path}:PREFIX instead.")
        return load_hloc_global(path, prefix)[0]
    if mmap_mode not in (None, "r", "c"):
        raise InvalidParameterError(
            f"mmap_mode must be None, 'r' or 'c'; got {mmap_mode!r} (writable maps could change the file)."
        )
    if not path.exists():
        raise DataNotFoundError(f"descriptor file {str(path)!r} does not exist. Check the path.")
    if not path.is_file():
        raise DataNotFoundError(f"{str(path)!r} is a folder; pass the .npy file inside it.")
    with open_regular(path):
        pass
    if mmap_mode is None:
        check_numpy_file(path, f"descriptor file {str(path)!r}")
    try:
        loaded = np.load(path, mmap_mode=mmap_mode, allow_pickle=False)
    except ValueError as exc:
        if "pickle" in str(exc).lower():
            raise InvalidDescriptorsError(
                f"{str(path)!r} holds Python objects (a pickled array); btel never unpickles files because "
                "that can run code. Save the descriptors as a numeric array: np.save(path, X.astype('float32'))."
            ) from exc
        raise InvalidDescriptorsError(f"{str(path)!r} is not a valid .npy file: {exc}") from exc
    except Exception as exc:  # OSError, EOFError, BadZipFile, zlib.error, tokenize's TokenError…: a bad file
        raise InvalidDescriptorsError(
            f"{str(path)!r} is not a readable .npy/.npz file ({type(exc).__name__}: {str(exc)[:200]})."
        ) from exc

    if isinstance(loaded, np.lib.npyio.NpzFile):
        with loaded:
            if mmap_mode is not None:
                raise InvalidParameterError(f"{str(path)!r} is an .npz archive; memory-mapping needs a .npy file.")
            names = list(loaded.files)
            if key is None:
                if len(names) != 1:
                    raise InvalidParameterError(
                        f"{str(path)!r} holds {len(names)} arrays ({', '.join(names)}); choose one: {path}:{names[0]} "
                        f"on the command line, key={names[0]!r} in Python."
                    )
                key = names[0]
            if key not in names:
                raise DataNotFoundError(f"{str(path)!r} has no array {key!r}; it holds: {', '.join(names)}.")
            try:
                array = loaded[key]
            except ValueError as exc:
                if "pickle" not in str(exc).lower():
                    raise InvalidDescriptorsError(f"array {key!r} in {str(path)!r} is not a valid .npy array: "
                                                  f"{str(exc)[:200]}") from exc
                raise InvalidDescriptorsError(
                    f"array {key!r} in {str(path)!r} holds Python objects; btel never unpickles files."
                ) from exc
            except Exception as exc:  # a damaged archive: bad CRC, truncated member, odd compression…
                raise InvalidDescriptorsError(
                    f"{str(path)!r} is a damaged .npz archive; array {key!r} cannot be read "
                    f"({type(exc).__name__}: {str(exc)[:200]})."
                ) from exc
        name = f"{key!r} in {path.name}"
    else:
        if key is not None:
            raise InvalidParameterError(f"key={key!r} only applies to .npz archives; {str(path)!r} is a .npy file.")
        array = loaded
        name = f"descriptors in {path.name}"
    return check_descriptors(array, name=name)
