"""Descriptor matrices computed by other tools (NetVLAD, DenseVLAD in MATLAB, ...) as ``.npy``.

Row i is the global descriptor of image (place) i. Files are read with ``allow_pickle=False``:
nothing in a descriptor file can run code.
"""

from __future__ import annotations

import os
import zipfile
from pathlib import Path

import numpy as np

from .._validation import check_descriptors
from ..exceptions import DataNotFoundError, InvalidDescriptorsError, InvalidParameterError

__all__ = ["load_descriptor_matrix"]


def load_descriptor_matrix(
    path: str | os.PathLike, *, mmap_mode: str | None = None, key: str | None = None
) -> np.ndarray:
    """Load and check an ``(n, d)`` descriptor matrix from a ``.npy`` (or ``.npz``) file.

    Parameters
    ----------
    path : str or path-like
        A ``.npy`` file, or an ``.npz`` archive (then ``key`` names the array; it may be left
        out when the archive holds exactly one).
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
    path = Path(path)
    if mmap_mode not in (None, "r", "c"):
        raise InvalidParameterError(
            f"mmap_mode must be None, 'r' or 'c'; got {mmap_mode!r} (writable maps could change the file)."
        )
    if not path.exists():
        raise DataNotFoundError(f"descriptor file {str(path)!r} does not exist. Check the path.")
    if not path.is_file():
        raise DataNotFoundError(f"{str(path)!r} is a folder; pass the .npy file inside it.")
    try:
        loaded = np.load(path, mmap_mode=mmap_mode, allow_pickle=False)
    except ValueError as exc:
        if "pickle" in str(exc).lower():
            raise InvalidDescriptorsError(
                f"{str(path)!r} holds Python objects (a pickled array); btel never unpickles files because "
                "that can run code. Save the descriptors as a numeric array: np.save(path, X.astype('float32'))."
            ) from exc
        raise InvalidDescriptorsError(f"{str(path)!r} is not a valid .npy file: {exc}") from exc
    except (OSError, EOFError, zipfile.BadZipFile) as exc:
        raise InvalidDescriptorsError(
            f"{str(path)!r} is not a readable .npy/.npz file ({type(exc).__name__}: {exc})."
        ) from exc

    if isinstance(loaded, np.lib.npyio.NpzFile):
        with loaded:
            if mmap_mode is not None:
                raise InvalidParameterError(f"{str(path)!r} is an .npz archive; memory-mapping needs a .npy file.")
            names = list(loaded.files)
            if key is None:
                if len(names) != 1:
                    raise InvalidParameterError(
                        f"{str(path)!r} holds {len(names)} arrays ({', '.join(names)}); choose one with key=."
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
