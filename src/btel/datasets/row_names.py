"""The image of every row of a descriptor file: its name, and its file when still on disk.

``btel extract`` writes a ``.json`` beside each ``.npy`` listing its images (and, since the
folder was recorded, where they are); an hloc ``.h5`` names every row by its group. These names
let predictions, retrieval pairs and galleries speak of images, not row numbers.
"""

from __future__ import annotations

import os
from pathlib import Path

__all__ = ["row_names", "row_images"]


def _sidecar(path: str | os.PathLike) -> dict | None:
    """The record ``btel extract`` wrote beside ``path`` when it is a JSON object, else None (no record, or
    JSON of another shape: no names). One that cannot be read (not a regular file, too large, not JSON) is
    an error, as for every reader of it (:func:`btel.descriptors.npy_header.read_sidecar`)."""
    from ..descriptors.npy_header import read_sidecar

    key = read_sidecar(path)
    return key if isinstance(key, dict) else None


def row_names(path: str | os.PathLike) -> list[str] | None:
    """The image name of every row of the descriptor file ``path``, or None when it records none.

    ``.npy`` written by ``btel extract``: the images in its sidecar ``PATH.json``; hloc ``.h5``
    (``FILE.h5:PREFIX`` too): the group names, in the rows' order.

    Raises
    ------
    InvalidDescriptorsError
        The sidecar exists but cannot be read (:func:`btel.descriptors.npy_header.read_sidecar`): an error,
        not names silently dropped.
    """
    from ..descriptors.npy import HDF5_SUFFIXES, load_hloc_global, split_prefix

    file, prefix = split_prefix(path)
    if file.suffix.lower() in HDF5_SUFFIXES:
        return load_hloc_global(file, prefix)[1]
    if file.suffix.lower() != ".npy" or (key := _sidecar(file)) is None:
        return None
    return _recorded_names(key, file)


def _damaged(path: str | os.PathLike, what: str) -> Exception:
    from ..exceptions import InvalidDescriptorsError

    return InvalidDescriptorsError(f"{path}.json: {what}, not as btel extract writes it (the record was edited or "
                                   f"damaged); extract the descriptors again, or delete {path}.json to use the "
                                   "matrix without image names.")


def _recorded_names(key: dict, path: str | os.PathLike) -> list[str] | None:
    """The image names of a record (``"images"``: ``[[name, size, mtime], …]``); None when it lists none."""
    images = key.get("images")
    if images is None:
        return None
    if not isinstance(images, list) or not all(isinstance(e, list) and e and isinstance(e[0], str) for e in images):
        raise _damaged(path, '"images" is not a list of [name, size, time] entries')
    return [entry[0] for entry in images]


def row_images(path: str | os.PathLike | None) -> list[Path] | None:
    """The image file of every row of the descriptors ``path`` (from ``btel extract``'s .json), or
    None when they are not recorded or no longer on disk.

    Raises
    ------
    InvalidParameterError
        A recorded name is not a plain file name inside the folder (``../x``, a control character).
    InvalidDescriptorsError
        The sidecar exists but cannot be read (see :func:`row_names`).
    """
    from .vpr_names import check_image_names

    key = _sidecar(path) if path else None
    folder = None if key is None else key.get("folder")
    if folder is None or folder == "":  # not recorded (records of before the folder was)
        return None
    if not isinstance(folder, str):
        raise _damaged(path, '"folder" is not a path')
    names = _recorded_names(key, path)
    if names is None:
        return None
    check_image_names(names, f"{path}.json", file_name=True)  # images inside the folder, nowhere else
    files = [Path(folder) / name for name in names]
    try:
        return files if files and all(f.is_file() for f in files) else None
    except OSError as exc:  # a folder name too long for the system, say
        raise _damaged(path, f'"folder" cannot be a folder here ({exc.strerror})') from None
