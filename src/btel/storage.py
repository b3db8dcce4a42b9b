"""Storage accounting and model files.

The storage rule (SPEC §7), for every method in btel: **a model's storage is the sum of
``ndarray.nbytes`` over the arrays that inference reads, at their stored dtype.** A model file
holds exactly those arrays plus a small JSON header, so ``file size − reported bytes`` is only
the container overhead (a few hundred bytes per array; checked ≤ 4 KiB in the tests).

Model files are uncompressed ``.npz`` archives read with ``allow_pickle=False``: nothing in a
file can execute code. The header is stored as a uint8 array named ``__btel_header__`` that
holds UTF-8 JSON with the format name, the format version, the model class and its parameters.
"""

from __future__ import annotations

import json
import os
import re
import zipfile
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from .exceptions import BudgetExceededError, InvalidParameterError, ModelFileError, UnsupportedModelVersionError

__all__ = [
    "check_within_budget",
    "FORMAT_NAME",
    "FORMAT_VERSION",
    "parse_budget",
    "format_bytes",
    "storage_breakdown",
    "save_arrays",
    "load_arrays",
]

FORMAT_NAME = "btel-model"
FORMAT_VERSION = 1
HEADER_KEY = "__btel_header__"

_UNITS = {
    "": 1,
    "B": 1,
    "KB": 1000,
    "MB": 1000**2,
    "GB": 1000**3,
    "KIB": 1024,
    "MIB": 1024**2,
    "GIB": 1024**3,
}


def parse_budget(budget: int | float | str | None) -> int | None:
    """Turn a byte budget into an integer number of bytes.

    Decimal units as in the paper (``KB`` = 1000 B, ``MB`` = 10^6 B); binary units are
    spelled ``KiB``/``MiB``. Case-insensitive, spaces allowed: ``"500KB"``, ``"2 MB"``,
    ``"64KiB"``, ``1_000_000``.

    Returns
    -------
    int or None
        Bytes, or None when ``budget`` is None (no budget).
    """
    if budget is None:
        return None
    if isinstance(budget, bool):
        raise InvalidParameterError(f"budget must be a number of bytes or a string like '500KB'; got {budget!r}.")
    if isinstance(budget, (int, np.integer)):
        value = float(budget)
    elif isinstance(budget, (float, np.floating)):
        value = float(budget)
    elif isinstance(budget, str):
        match = re.fullmatch(r"\s*([0-9]*\.?[0-9]+(?:[eE][+-]?[0-9]+)?)\s*([A-Za-z]*)\s*", budget)
        unit = match.group(2).upper() if match else None
        if match is None or unit not in _UNITS:
            raise InvalidParameterError(
                f"budget {budget!r} is not understood; write bytes or a size such as '500KB', "
                "'2MB' or '64KiB' (KB = 1000 B, KiB = 1024 B)."
            )
        value = float(match.group(1)) * _UNITS[unit]
    else:
        raise InvalidParameterError(f"budget must be a number of bytes or a string like '500KB'; got {budget!r}.")
    if not np.isfinite(value) or value <= 0:
        raise InvalidParameterError(f"budget must be a positive number of bytes; got {budget!r}.")
    return int(value)


def format_bytes(n_bytes: float) -> str:
    """Human-readable decimal size: ``format_bytes(492240) == '492.2 KB'``."""
    for unit, size in (("GB", 1e9), ("MB", 1e6), ("KB", 1e3)):
        if n_bytes >= size:
            return f"{n_bytes / size:.1f} {unit}"
    return f"{int(n_bytes)} B"


def storage_breakdown(arrays: Mapping[str, np.ndarray]) -> dict[str, int]:
    """Bytes per stored array: the one storage rule every method uses.

    Parameters
    ----------
    arrays : mapping of str to ndarray
        The arrays inference reads, at their stored dtype.

    Returns
    -------
    dict of str to int
        ``{name: array.nbytes}``; the model's storage is the sum of the values.
    """
    return {name: int(np.asarray(a).nbytes) for name, a in arrays.items()}


def save_arrays(path: str | os.PathLike, arrays: Mapping[str, np.ndarray], header: Mapping[str, Any]) -> Path:
    """Write arrays plus a JSON header as an uncompressed ``.npz`` model file.

    ``header`` must be JSON-serialisable; the format name and version are added here.
    Writing goes to a temporary file that is renamed into place, so an interrupted save
    never leaves a half-written model under the requested name.
    """
    path = Path(path)
    if HEADER_KEY in arrays:
        raise InvalidParameterError(f"{HEADER_KEY!r} is reserved for the model header.")
    for name, a in arrays.items():
        if np.asarray(a).dtype == object:
            raise InvalidParameterError(f"array {name!r} has dtype object; model files hold plain arrays only.")
    full_header = {"format": FORMAT_NAME, "format_version": FORMAT_VERSION, **header}
    header_bytes = np.frombuffer(json.dumps(full_header, sort_keys=True).encode("utf-8"), dtype=np.uint8)
    if path.parent and not path.parent.exists():
        path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".part")
    with open(tmp, "wb") as fh:
        np.savez(fh, **{HEADER_KEY: header_bytes}, **{k: np.asarray(v) for k, v in arrays.items()})
    os.replace(tmp, path)
    return path


def load_arrays(path: str | os.PathLike) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    """Read a model file written by :func:`save_arrays`, never unpickling anything.

    Returns
    -------
    arrays : dict of str to ndarray
    header : dict
        The JSON header.

    Raises
    ------
    ModelFileError
        The file is missing, truncated, corrupt, or not a btel model.
    UnsupportedModelVersionError
        The file's format version is newer than this btel can read.
    """
    path = Path(path)
    if not path.exists():
        raise ModelFileError(f"model file {str(path)!r} does not exist. Train one with BTELocalizer.fit(...).save(path) or `btel train`.")
    if path.is_dir():
        raise ModelFileError(f"{str(path)!r} is a folder, not a model file.")
    try:
        # Our own handle: np.load leaks the file it opened when the zip is truncated.
        with open(path, "rb") as fh:
            # A model file is a zip (.npz). Anything else would reach np.load's .npy or pickle
            # branches: an ndarray (no context manager) or a misleading "pickled data" error.
            if fh.read(4) != b"PK\x03\x04":
                raise ModelFileError(
                    f"{str(path)!r} is corrupt or not a btel model file (not an .npz archive). "
                    "Load models saved by btel only; save the model again if this was one."
                )
            fh.seek(0)
            with np.load(fh, allow_pickle=False) as npz:
                names = list(npz.files)
                if HEADER_KEY not in names:
                    raise ModelFileError(
                        f"{str(path)!r} is an .npz file but not a btel model (no btel header). "
                        "Load descriptors with numpy; load models saved by btel only."
                    )
                arrays = {name: npz[name] for name in names}
    except ModelFileError:
        raise
    except ValueError as exc:
        if "pickle" in str(exc).lower():
            raise ModelFileError(
                f"{str(path)!r} contains pickled objects; btel never loads pickles (they can run code). "
                "It is not a btel model file."
            ) from exc
        raise ModelFileError(f"{str(path)!r} is corrupt or not a btel model file: {exc}") from exc
    except (OSError, EOFError, zipfile.BadZipFile, KeyError) as exc:
        raise ModelFileError(
            f"{str(path)!r} is truncated, corrupt or not a btel model file ({type(exc).__name__}: {exc}). "
            "Save the model again."
        ) from exc
    raw = arrays.pop(HEADER_KEY)
    try:
        header = json.loads(raw.astype(np.uint8).tobytes().decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ModelFileError(f"{str(path)!r} has a corrupt header: {exc}") from exc
    if not isinstance(header, dict) or header.get("format") != FORMAT_NAME:
        raise ModelFileError(f"{str(path)!r} is not a btel model file (foreign header).")
    version = header.get("format_version")
    if not isinstance(version, int):
        raise ModelFileError(f"{str(path)!r} has no valid format version in its header.")
    if version > FORMAT_VERSION:
        raise UnsupportedModelVersionError(
            f"{str(path)!r} uses model format version {version}, newer than this btel reads "
            f"(≤ {FORMAT_VERSION}). Upgrade btel (pip install -U btel) to load it."
        )
    return arrays, header


def check_within_budget(label: str, nbytes: int | None, budget: int | None) -> None:
    """Fail the run when a method stored more than its budget: a bug in its budget fitting."""
    if budget is not None and nbytes is not None and nbytes > budget:
        raise BudgetExceededError(
            f"{label} stores {nbytes} B, over its budget of {budget} B: a bug in its budget fitting."
        )
