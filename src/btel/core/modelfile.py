"""Model files: plain arrays plus a JSON header, written atomically and parsed as hostile input.

Model files are uncompressed ``.npz`` archives holding exactly the arrays inference reads (their
bytes are the model's storage, :mod:`btel.core.storage`). The header is stored as a uint8 array named
``__btel_header__`` that holds UTF-8 JSON with the format name, the format version, the model
class and its parameters. A file is untrusted input: :func:`load_arrays` reads it with its own
checks (zip directory, then JSON header, then each ``.npy`` header) before allocating anything,
never unpickles, and turns every failure into a :class:`~btel.exceptions.ModelFileError`.
:func:`save_arrays` writes atomically (a unique temporary file, then a rename or, without
``overwrite``, a link that never replaces a file).
"""

from __future__ import annotations

import datetime as _dt
import json
import math
import os
import zipfile
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from ..exceptions import (DataNotFoundError, InvalidParameterError, ModelFileError, OutputExistsError,
                         ResourceLimitError, UnsupportedModelVersionError)
from .claims import atomic_output
from .limits import check_zip_members, open_regular

__all__ = ["ArraySpec", "FORMAT_NAME", "FORMAT_VERSION", "HEADER_KEY", "jsonable", "save_arrays", "load_arrays"]

FORMAT_NAME = "btel-model"
FORMAT_VERSION = 1
HEADER_KEY = "__btel_header__"


class ArraySpec:
    """Shape and dtype a stored array must have (``None`` in the shape: any length on that axis).

    ``dtype`` may be a tuple of allowed dtypes (e.g. the smallest unsigned integer of a table).
    """

    def __init__(self, shape: tuple[int | None, ...], dtype: Any, *, required: bool = True) -> None:
        self.shape = tuple(shape)
        self.dtypes = tuple(np.dtype(t) for t in (dtype if isinstance(dtype, tuple) else (dtype,)))
        self.required = required

    @property
    def nbytes(self) -> int:
        """Bytes of an array of this spec (all axes known; the first allowed dtype)."""
        return int(np.prod(self.shape, dtype=np.int64)) * self.dtypes[0].itemsize

    def matches(self, array: np.ndarray) -> bool:
        return array.dtype in self.dtypes and array.ndim == len(self.shape) and all(
            want is None or want == got for want, got in zip(self.shape, array.shape))

    def describe(self) -> str:
        dims = ", ".join("n" if s is None else str(s) for s in self.shape)
        return f"({dims}){',' if len(self.shape) == 1 else ''} {'/'.join(t.name for t in self.dtypes)}"


def save_arrays(path: str | os.PathLike, arrays: Mapping[str, np.ndarray], header: Mapping[str, Any],
                overwrite: bool | None = None) -> Path:
    """Write arrays plus a JSON header as an uncompressed ``.npz`` model file, atomically.

    ``header`` must be JSON-serialisable; the format name and version are added here. The file is
    written to a temporary file of a unique name in the same folder, flushed to disk and then
    published under ``path`` in one step (:func:`btel.core.claims.atomic_output`), so a reader only
    ever sees the old file or the whole new one, two saves to one path at once cannot mix their
    bytes, and an interrupted or failed save removes its temporary file. ``overwrite=None`` (the
    default) replaces an existing btel file (a model saved again) and keeps any other file (a
    descriptor matrix, a text file: never lost to a mistyped name); ``True`` replaces anything;
    ``False`` never replaces, not even a file another process writes during this save.

    Raises
    ------
    InvalidParameterError
        ``path`` is empty, an existing folder, or lies under a regular file; a reserved or
        non-numeric array.
    OutputExistsError
        ``path`` exists and ``overwrite`` is False, or None and the file is not btel's; nothing was replaced.
    ModelFileError
        Writing failed (disk full, no permission…); nothing is left behind.
    """
    if not isinstance(path, (str, os.PathLike)):
        raise InvalidParameterError(f"the model path must be a string or a path; got {type(path).__name__}.")
    if isinstance(path, str) and not path.strip():
        raise InvalidParameterError("the model path is empty; give a file name such as 'map.btel.npz'.")
    path = Path(path).expanduser()  # '~/m.btel.npz' is the home folder's, not a folder named '~'
    if path.is_dir():
        raise InvalidParameterError(f"{str(path)!r} is a folder; give a file name inside it, e.g. "
                                    f"{str(path / 'map.btel.npz')!r}.")
    if HEADER_KEY in arrays:
        raise InvalidParameterError(f"{HEADER_KEY!r} is reserved for the model header.")
    for name, a in arrays.items():
        dtype = np.asarray(a).dtype
        if dtype.kind not in _ARRAY_KINDS or dtype.hasobject:
            raise InvalidParameterError(
                f"array {name!r} has dtype {dtype}; model files hold plain numeric arrays only.")
    import importlib.metadata

    try:
        version = importlib.metadata.version("btel")
    except importlib.metadata.PackageNotFoundError:  # a source tree on the path, not installed
        version = "unknown"
    # Which btel wrote the file, and when (``btel info`` shows it; nothing reads it back into the model).
    saved_by = {"btel": version, "date_utc": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds")}
    full_header = {"format": FORMAT_NAME, "format_version": FORMAT_VERSION, "saved_by": saved_by, **header}
    header_bytes = np.frombuffer(json.dumps(full_header, sort_keys=True, allow_nan=False).encode("utf-8"),
                                 dtype=np.uint8)
    folder = path.parent
    for parent in (folder, *folder.parents):
        if parent.exists():
            if not parent.is_dir():
                raise InvalidParameterError(
                    f"cannot save to {str(path)!r}: {str(parent)!r} is a file, not a folder.")
            break
    if overwrite is None and os.path.lexists(path) and not _is_btel_file(path):
        raise OutputExistsError(f"{str(path)!r} exists and is not a btel file (a model or descriptor btel saved); it "
                                "was kept. Choose another name, or pass overwrite=True to replace it.")
    if overwrite is False and path.exists():
        raise _taken_before(path)
    try:
        folder.mkdir(parents=True, exist_ok=True)
        with atomic_output(path, overwrite=overwrite is not False) as fh:
            np.savez(fh, **{HEADER_KEY: header_bytes}, **{k: np.asarray(v) for k, v in arrays.items()})
    except OutputExistsError:
        raise
    except OSError as exc:
        raise ModelFileError(f"cannot save the model to {str(path)!r}: {exc.strerror or exc}.") from exc
    return path


def _is_btel_file(path: Path) -> bool:
    """A regular file that is an .npz holding btel's header member (read from the zip directory only)."""
    try:
        with open_regular(path) as fh:
            if fh.read(4) != b"PK\x03\x04":
                return False
            check_zip_members(fh, str(path), MAX_MEMBERS)
            with zipfile.ZipFile(fh) as archive:
                return HEADER_KEY + ".npy" in archive.namelist()
    except Exception:  # noqa: BLE001 - unreadable, not a zip, too many members: not a file btel wrote
        return False


def _taken_before(path: Path) -> OutputExistsError:
    return OutputExistsError(f"{str(path)!r} already exists; it was kept. Pass overwrite=True "
                             "(CLI: --overwrite) to replace it, or choose another name.")


#: Array dtypes a model file may hold: booleans, integers and real floats (no objects, strings,
#: complex numbers, dates or records).
_ARRAY_KINDS = "biuf"
#: Largest JSON header read (bytes); real headers are a few hundred bytes.
MAX_HEADER_BYTES = 1 << 20
#: Deepest nesting of lists/objects accepted in the header (real headers nest 4 deep).
MAX_HEADER_DEPTH = 16
#: Most digits of an integer in the header (2**64 has 20).
MAX_HEADER_INT_DIGITS = 24
#: Most members (arrays) in a model file.
MAX_MEMBERS = 1024
#: Most dimensions of a stored array.
MAX_NDIM = 8
#: Largest .npy header of a member (numpy writes 128 bytes for ordinary arrays).
_MAX_NPY_HEADER = 4096
#: Bytes read at a time into an array (bounds the temporary copies to this much).
_READ_CHUNK = 1 << 24


def load_arrays(path: str | os.PathLike) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    """Read a model file written by :func:`save_arrays`, treating it as untrusted input.

    Nothing is unpickled and nothing is allocated before the file has shown it holds it: the zip
    directory is checked first (only uncompressed, unencrypted ``.npy`` members with distinct names,
    declared sizes that fit in the file and together not larger than it), then the JSON header
    (bounded size, nesting and numbers; no NaN/Infinity), then each array's ``.npy`` header (a plain
    numeric dtype, at most 8 dimensions, and a shape whose byte size equals the member's size)
    before its bytes are read. Any failure is a :class:`ModelFileError` with a message.

    Returns
    -------
    arrays : dict of str to ndarray
        Native byte order, C-contiguous, writable.
    header : dict
        The JSON header.

    Raises
    ------
    ModelFileError
        The file is missing, truncated, corrupt, edited beyond what btel writes, or not a btel model.
    UnsupportedModelVersionError
        The file's format version is newer than this btel can read.
    """
    if not isinstance(path, (str, os.PathLike)):
        raise InvalidParameterError(f"a model path must be a string or a path; got {type(path).__name__}.")
    path = Path(path)
    where = repr(str(path))
    try:
        exists, is_dir = path.exists(), path.is_dir()
    except (OSError, ValueError) as exc:  # a name too long, an embedded NUL byte…
        raise ModelFileError(f"{where[:200]} cannot be read as a model file ({exc}).") from exc
    if not exists and path.is_symlink():
        raise ModelFileError(f"model file {where} is a link that leads nowhere (a missing target, or a loop of "
                             "links). Check the link.")
    if not exists:
        raise ModelFileError(f"model file {where} does not exist. Train one with `btel train` or, in Python, model.fit(X).save(path).")
    if is_dir:
        raise ModelFileError(f"{where} is a folder, not a model file.")
    try:
        # Our own handle: np.load leaks the file it opened when the zip is truncated.
        with open_regular(path) as fh:  # a FIFO or device is refused without blocking
            # A model file is a zip (.npz). Anything else would reach np.load's .npy or pickle
            # branches: an ndarray (no context manager) or a misleading "pickled data" error.
            if fh.read(4) != b"PK\x03\x04":
                raise ModelFileError(
                    f"{where} is corrupt or not a btel model file (not an .npz archive). "
                    "Load models saved by btel only; save the model again if this was one."
                )
            file_size = os.fstat(fh.fileno()).st_size
            try:  # before ZipFile parses the whole directory (10⁶ entries: 18 s, 1.1 GB)
                check_zip_members(fh, where, MAX_MEMBERS)
            except ResourceLimitError as exc:
                raise ModelFileError(f"{exc} It is not a btel model; save the model again.") from None
            with zipfile.ZipFile(fh) as archive:
                members = _checked_members(archive, file_size, where)
                header = _read_header(archive, members.pop(HEADER_KEY), where)
                arrays = {name: _read_member(archive, info, name, where) for name, info in members.items()}
    except ModelFileError:
        raise
    except DataNotFoundError as exc:  # open_regular: not a regular file
        raise ModelFileError(str(exc)) from None
    except Exception as exc:  # zipfile, struct, OSError, EOFError, MemoryError…: all mean a bad file
        raise ModelFileError(
            f"{where} is truncated, corrupt or not a btel model file ({type(exc).__name__}: {str(exc)[:200]}). "
            "Save the model again."
        ) from exc
    return arrays, header


def _checked_members(archive: zipfile.ZipFile, file_size: int, where: str) -> dict[str, zipfile.ZipInfo]:
    """The archive's members by array name, after checking the zip directory (nothing read yet)."""
    infos = archive.infolist()
    names = [info.filename for info in infos]
    if HEADER_KEY + ".npy" not in names:
        raise ModelFileError(
            f"{where} is an .npz file but not a btel model (no btel header). "
            "Load descriptors with numpy; load models saved by btel only."
        )
    if len(infos) > MAX_MEMBERS:
        raise ModelFileError(f"{where} holds {len(infos)} members; a btel model holds at most {MAX_MEMBERS}.")
    members: dict[str, zipfile.ZipInfo] = {}
    total = 0
    for info in infos:
        name = info.filename
        if not name.endswith(".npy") or len(name) > 256:
            raise ModelFileError(f"{where} holds the member {name[:60]!r}, which is not an array (.npy); "
                                 "btel model files hold arrays only.")
        key = name[: -len(".npy")]
        if key in members:
            raise ModelFileError(f"{where} holds the array {key[:60]!r} twice; the file was edited.")
        if info.flag_bits & 0x1:
            raise ModelFileError(f"{where}: the member {name[:60]!r} is encrypted; btel model files are not.")
        if info.compress_type != zipfile.ZIP_STORED:
            raise ModelFileError(
                f"{where}: the member {name[:60]!r} is compressed (zip method {info.compress_type}); btel writes "
                "uncompressed model files only and does not inflate archives (a small file can expand to gigabytes)."
            )
        if info.file_size != info.compress_size or info.file_size > file_size:
            raise ModelFileError(
                f"{where}: the member {name[:60]!r} declares {info.file_size} B in a file of {file_size} B; "
                "the file is truncated or was edited."
            )
        total += info.file_size
        members[key] = info
    if total > file_size:
        raise ModelFileError(f"{where}: its members declare {total} B together in a file of {file_size} B "
                             "(overlapping members); the file was edited.")
    return members


class _CountingReader:
    """A file object that counts the bytes read through it (the length of a .npy header)."""

    def __init__(self, raw: Any) -> None:
        self.raw, self.count = raw, 0

    def read(self, n: int = -1) -> bytes:
        if n is None or n < 0 or n > _MAX_NPY_HEADER:
            raise ModelFileError(f"an array header longer than {_MAX_NPY_HEADER} B")
        data = self.raw.read(n)
        self.count += len(data)
        return data


def _npy_header(member: Any, name: str, where: str) -> tuple[tuple[int, ...], bool, np.dtype, int]:
    """(shape, fortran order, dtype, header length) of a member's .npy header, all checked."""
    reader = _CountingReader(member)
    try:
        version = np.lib.format.read_magic(reader)
        if version == (1, 0):
            shape, fortran, dtype = np.lib.format.read_array_header_1_0(reader, max_header_size=_MAX_NPY_HEADER)
        elif version == (2, 0):
            shape, fortran, dtype = np.lib.format.read_array_header_2_0(reader, max_header_size=_MAX_NPY_HEADER)
        else:
            raise ValueError(f"unsupported .npy format version {version}")
    except ModelFileError as exc:
        raise ModelFileError(f"{where}: the array {name[:60]!r} has {exc}; the file is corrupt or was edited.") from exc
    except Exception as exc:  # ValueError, tokenize.TokenError, SyntaxError, RecursionError, MemoryError…
        raise ModelFileError(f"{where}: the array {name[:60]!r} has a corrupt header ({type(exc).__name__}: "
                             f"{str(exc)[:120]}); the file is corrupt or was edited.") from exc
    if dtype.hasobject:
        raise ModelFileError(
            f"{where} contains pickled objects; btel never loads pickles (they can run code). The array "
            f"{name[:60]!r} holds Python objects: it is not a btel model file."
        )
    if dtype.kind not in _ARRAY_KINDS or dtype.fields is not None or dtype.subdtype is not None:
        raise ModelFileError(f"{where}: the array {name[:60]!r} has dtype {str(dtype)[:40]}; btel model files hold "
                             "booleans, integers and real floats only.")
    if not isinstance(shape, tuple) or len(shape) > MAX_NDIM or \
            not all(isinstance(n, int) and not isinstance(n, bool) and n >= 0 for n in shape):
        raise ModelFileError(f"{where}: the array {name[:60]!r} declares the shape {str(shape)[:60]}.")
    return shape, bool(fortran), dtype, reader.count


def _read_member(archive: zipfile.ZipFile, info: zipfile.ZipInfo, name: str, where: str) -> np.ndarray:
    """One array: its .npy header checked against the member's size, then exactly its bytes."""
    with archive.open(info) as member:
        shape, fortran, dtype, header_len = _npy_header(member, name, where)
        n_bytes = math.prod(shape) * dtype.itemsize  # Python ints: no overflow
        if n_bytes != info.file_size - header_len:
            raise ModelFileError(
                f"{where}: the array {name[:60]!r} declares shape {shape[:MAX_NDIM]} of {dtype} ({n_bytes} B) "
                f"but holds {info.file_size - header_len} B; the file is truncated or was edited."
            )
        buffer = bytearray(n_bytes)
        view, done = memoryview(buffer), 0
        while done < n_bytes:  # in chunks: zipfile reads each request into a temporary bytes object
            got = member.readinto(view[done : done + _READ_CHUNK])
            if not got:
                raise ModelFileError(f"{where}: the array {name[:60]!r} is truncated.")
            done += got
        member.read()  # reach the member's end: zipfile checks its CRC there
    array = np.frombuffer(buffer, dtype=dtype)
    array = array.reshape(shape[::-1]).T if fortran else array.reshape(shape)
    if not dtype.isnative:
        array = array.astype(dtype.newbyteorder("="))
    return np.ascontiguousarray(array)


def _read_header(archive: zipfile.ZipFile, info: zipfile.ZipInfo, where: str) -> dict[str, Any]:
    """The JSON header: a uint8 vector of UTF-8, bounded, parsed strictly, then checked."""
    if info.file_size > MAX_HEADER_BYTES:
        raise ModelFileError(f"{where} has a header of {info.file_size} B; btel headers are under {MAX_HEADER_BYTES} B.")
    raw = _read_member(archive, info, HEADER_KEY, where)
    if raw.dtype != np.uint8 or raw.ndim != 1:
        raise ModelFileError(f"{where} has a corrupt header (an array of {raw.dtype} and shape {raw.shape}, "
                             "not UTF-8 bytes).")
    try:
        header = json.loads(raw.tobytes().decode("utf-8"), parse_constant=_parse_constant,
                            parse_float=_finite_float, parse_int=_bounded_int)
        state = header.get("state") if isinstance(header, dict) else None
        if isinstance(state, dict) and state.get("fit_time") is _NAN:
            # Earlier btel saved a loaded model's unknown fit time as NaN: read it as unknown.
            state["fit_time"] = None
        _check_values(header)
    except RecursionError as exc:
        raise ModelFileError(f"{where} has a corrupt header (nested too deeply).") from exc
    except (UnicodeDecodeError, ValueError) as exc:
        raise ModelFileError(f"{where} has a corrupt header: {str(exc)[:200]}") from exc
    if not isinstance(header, dict) or header.get("format") != FORMAT_NAME:
        raise ModelFileError(f"{where} is not a btel model file (foreign header).")
    version = header.get("format_version")
    if isinstance(version, bool) or not isinstance(version, int):
        raise ModelFileError(f"{where} has no valid format version in its header.")
    if version > FORMAT_VERSION:
        raise UnsupportedModelVersionError(
            f"{where} uses model format version {version}, newer than this btel reads "
            f"(≤ {FORMAT_VERSION}). Upgrade btel (pip install -U btel) to load it."
        )
    if version < 1:
        raise ModelFileError(f"{where} has an invalid format version {version}.")
    return header


#: Stands for the JSON constant NaN while the header is checked (refused anywhere but state.fit_time).
_NAN = type("_NaNConstant", (), {"__repr__": lambda self: "NaN"})()


def _parse_constant(name: str) -> Any:
    if name == "NaN":
        return _NAN
    raise ValueError(f"{name} is not a number a btel header holds")


def _finite_float(text: str) -> float:
    value = float(text)
    if not math.isfinite(value):
        raise ValueError(f"the number {text[:40]} is out of range")
    return value


def _bounded_int(text: str) -> int:
    if len(text.lstrip("-")) > MAX_HEADER_INT_DIGITS:
        raise ValueError(f"an integer of {len(text)} digits")
    return int(text)


def _check_values(value: Any) -> None:
    """ValueError for a NaN, or lists/objects nested deeper than MAX_HEADER_DEPTH (iterative: no recursion)."""
    stack = [(value, 1)]
    while stack:
        item, depth = stack.pop()
        if item is _NAN:
            raise ValueError("NaN is not a number a btel header holds")
        if isinstance(item, (dict, list)):
            if depth > MAX_HEADER_DEPTH:
                raise ValueError(f"lists/objects nested more than {MAX_HEADER_DEPTH} deep")
            stack.extend((v, depth + 1) for v in (item.values() if isinstance(item, dict) else item))


def jsonable(value: Any) -> Any:
    """A JSON-safe form of a parameter value (model files, result records): numpy scalars as Python
    numbers, non-finite floats as None, types and dtypes by name, a nested method as its class and
    parameters, containers element by element, a large array by its shape."""
    if hasattr(value, "get_params") and hasattr(value, "_runtime_params"):  # a nested method (OPQ's pq)
        return {"estimator": type(value).__name__,
                "params": {k: jsonable(v) for k, v in value.get_params(deep=False).items()
                           if k not in value._runtime_params}}
    if isinstance(value, np.bool_):
        return bool(value)
    if isinstance(value, (np.integer,)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        return float(value) if np.isfinite(value) else None
    if isinstance(value, type):
        return np.dtype(value).name
    if isinstance(value, np.dtype):
        return value.name
    if isinstance(value, dict):
        return {str(k): jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [jsonable(v) for v in value]
    if isinstance(value, np.ndarray):
        return jsonable(value.tolist()) if value.size <= 64 else f"ndarray(shape={value.shape}, dtype={value.dtype})"
    return value
