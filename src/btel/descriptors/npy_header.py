"""What an ``.npy`` file's header announces, checked against the file before numpy maps or reads it.

numpy trusts the header: a file cut short (a copy or a download that did not finish) or one whose
header lies is reported by numpy as "mmap length is greater than file size", or by btel's memory
check as an allocation of many GiB, which sends the user after the wrong problem. An object dtype
(a pickle inside the ``.npy``) is reported by numpy's memory map as "Array can't be memory-mapped".
:func:`check_npy_header` names these before any read: only the header is parsed (numpy's own
parser, which evaluates no code), nothing is unpickled. :func:`read_sidecar` reads the JSON record
``btel extract`` writes beside an ``.npy`` (its images), bounded and from a regular file only.
"""

from __future__ import annotations

import json
import math
import os
import re
from pathlib import Path
from typing import Any

import numpy as np

from ..core.limits import format_size, open_regular
from ..exceptions import DataNotFoundError, InvalidDescriptorsError

__all__ = ["npy_header", "check_npy_header", "refuse_text_matrix", "read_sidecar", "MAX_SIDECAR_BYTES"]

_MAGIC = b"\x93NUMPY"
#: A cell of a text matrix that is a number (else the first line is a header). The fraction's digits
#: follow a point only: ``\d+\.?\d*`` could split a run of digits in every way, quadratic backtracking
#: on ``1111…1x`` (a 64 KiB first line took minutes).
_NUMBER = re.compile(r"\s*[-+]?(\d+(?:\.\d*)?|\.\d+)([eE][-+]?\d+)?\s*|\s*[-+]?(nan|inf)\s*", re.IGNORECASE)


def npy_header(path: str | os.PathLike) -> tuple[tuple[int, ...], np.dtype, int, int] | None:
    """(shape, dtype, bytes of data the header announces, bytes the file holds after its header) of
    the ``.npy`` file ``path``; None when it is not a regular file starting as an ``.npy`` or its
    header cannot be parsed (numpy's reader then names the problem)."""
    path = Path(path)
    if not path.is_file():  # a folder, a FIFO or a device: the readers refuse those themselves
        return None
    readers = {(1, 0): np.lib.format.read_array_header_1_0, (2, 0): np.lib.format.read_array_header_2_0}
    try:
        with open(path, "rb") as fh:
            if fh.read(len(_MAGIC)) != _MAGIC:
                return None
            fh.seek(0)
            reader: Any = readers.get(np.lib.format.read_magic(fh))
            if reader is None:
                return None
            shape, _fortran, dtype = reader(fh)
            offset = fh.tell()
            size = os.fstat(fh.fileno()).st_size
    except Exception:  # noqa: BLE001 - a damaged header: numpy's reader reports it when loading
        return None
    declared = math.prod(int(n) for n in shape) * dtype.itemsize  # Python ints: no overflow
    return tuple(int(n) for n in shape), dtype, declared, size - offset


def check_npy_header(path: str | os.PathLike, what: str, *, objects: bool = False) -> None:
    """Refuse an ``.npy`` whose header announces more data than the file holds (cut short, or not
    written by numpy) or less (data appended, a header edited: numpy would ignore the rest) and, unless ``objects``, one holding Python objects (a pickle), each with the
    fix. Anything else (not an ``.npy``, a damaged header) is left to the reader.

    Raises
    ------
    InvalidDescriptorsError
        The file is truncated or holds more than its header announces, or holds an object array
        (``objects=False``).
    """
    found = npy_header(path)
    if found is None:
        return
    shape, dtype, declared, held = found
    if dtype.hasobject:
        if objects:
            return  # a pickled payload has no size the header announces
        raise InvalidDescriptorsError(
            f"{what} {str(path)!r} holds Python objects (an object array, stored as a pickle); btel never "
            "unpickles files because that can run code. Save the descriptors as a numeric array: "
            "np.save(path, X.astype('float32')).")
    if any(n < 0 for n in shape):  # a hand-made header; numpy itself refuses to read it
        raise InvalidDescriptorsError(
            f"{what} {str(path)!r} has a header announcing a negative size, shape {shape}: it was not written by "
            "numpy (or was edited). Write the file again (np.save(path, X)).")
    if declared > held:
        raise InvalidDescriptorsError(
            f"{what} {str(path)!r} is cut short: its header announces an array of shape {shape} and dtype {dtype} "
            f"({format_size(declared)} of data) but the file holds {format_size(max(held, 0))} after the header "
            "(a copy or a write that did not finish, or a header that does not match the data). Copy or "
            "write the file again (np.save(path, X)).")
    if held > declared:  # numpy reads what the header says and ignores the rest: rows would vanish unsaid
        raise InvalidDescriptorsError(
            f"{what} {str(path)!r} holds {format_size(held)} after its header, more than the "
            f"{format_size(declared)} its shape {shape} and dtype {dtype} announce (a header edited, or data "
            "appended to the file): the rest would be ignored. Write the file again (np.save(path, X)).")


def refuse_text_matrix(path: str | os.PathLike, what: str) -> None:
    """A text matrix (numpy.savetxt, a CSV export, whatever its suffix) refused with the one command that
    converts it, its delimiter and header line read from the file's first lines."""
    file = Path(path)
    if not file.is_file():
        return
    try:
        with open(file, "rb") as fh:
            head = fh.read(1 << 16)
        text = head.decode("utf-8-sig")
    except (OSError, UnicodeDecodeError):
        return
    if text.lstrip().startswith("{") and file.suffix.lower() == ".json":
        # The record `btel extract` writes beside its matrix (X.npy.json), or any other JSON document.
        matrix = file.with_suffix("")
        beside = (f"; it describes {str(matrix)!r}, the matrix to give here" if matrix.suffix.lower() == ".npy"
                  and matrix.is_file() else "")
        raise InvalidDescriptorsError(
            f"{what} {str(file)!r} is a JSON document (such as the record `btel extract` writes beside its .npy), not "
            f"descriptors{beside}. btel reads .npy, .npz, hloc .h5 and folders of .npy shards.")
    lines = [line for line in text.splitlines() if line.strip() and not line.lstrip().startswith("#")][:2]
    if not lines or any(ch not in "\t\r\n" and not ch.isprintable() for ch in text):
        return
    # A European export: ';' between values and ',' as the decimal mark; a Unicode minus (U+2212) from a
    # spreadsheet. Both need a converter, or the suggested command fails on the first value.
    semicolon = ";" in lines[-1]
    fixes = ([".replace(',', '.')"] if semicolon and "," in lines[-1] else []) + (
        [".replace('\\u2212', '-')"] if "\u2212" in text else [])
    delimiter = ("';'" if semicolon else "','" if "," in lines[-1] else "'\\t'" if "\t" in lines[-1] else None)
    cells = [c.replace(",", ".").replace("\u2212", "-") if fixes else c
             for c in re.split(r"[;\t ]+" if semicolon else r"[,\t ]+", lines[0].strip()) if c]
    skip = 0 if all(_NUMBER.fullmatch(c) for c in cells) else 1
    target = file.with_name(file.stem + (".float32.npy" if file.suffix.lower() == ".npy" else ".npy"))
    options = ((f", delimiter={delimiter}" if delimiter else "") + (f", skiprows={skip}" if skip else "")
               + (f", converters=lambda s: float(s{''.join(fixes)})" if fixes else ""))
    raise InvalidDescriptorsError(
        f"{what} {str(file)!r} is a text matrix, not a .npy file; btel reads .npy, .npz, hloc .h5 and folders of "
        f".npy shards. Convert it once: python -c \"import numpy as np; np.save({str(target)!r}, "
        f"np.loadtxt({str(file)!r}{options}, dtype=np.float32, ndmin=2))\"")


#: Largest ``PATH.json`` record read beside a descriptor ``.npy`` (64 MiB): it holds one
#: ``[name, size, mtime]`` entry of about 80 bytes per image, room for 800,000 images (Pitts250k's map
#: has 254,000); a larger file is no record of btel's, and reading it whole would cost its size in memory.
MAX_SIDECAR_BYTES = 64 << 20


def read_sidecar(matrix: str | os.PathLike) -> Any:
    """The JSON record ``btel extract`` wrote beside the descriptor matrix ``matrix`` (``matrix + ".json"``:
    its images and how they were described), or None when there is none.

    A record that exists but cannot be read is an **error** (never a warning with the names dropped),
    for every reader: the image names of :func:`btel.datasets.row_names.row_names` and the cache checks
    of :mod:`btel.descriptors.extract`. Skipping it would silently write row numbers where names were
    expected, or recompute over a file btel did not vouch for. It is opened only as a regular file (a
    FIFO would block, a device such as ``/dev/zero`` never ends).

    Raises
    ------
    InvalidDescriptorsError
        The record is not a regular file, holds more than :data:`MAX_SIDECAR_BYTES`, or is not UTF-8
        JSON (or nests too deeply to parse); the message names it and the fix (delete it).
    """
    sidecar = Path(str(matrix) + ".json")
    if not os.path.lexists(sidecar):
        return None

    def refuse(why: str) -> InvalidDescriptorsError:
        return InvalidDescriptorsError(
            f"{str(sidecar)!r}, the record of the images beside the descriptor matrix {str(matrix)!r}, {why}. Delete "
            "it: without it the rows have no image names, and `btel extract` writes it anew with the matrix.")

    try:
        with open_regular(sidecar) as fh:
            data = fh.read(MAX_SIDECAR_BYTES + 1)  # one byte more than allowed: a larger file is caught
    except DataNotFoundError as exc:  # open_regular: os.open failed (its cause), or not a regular file
        cause = exc.__cause__
        raise refuse(f"cannot be opened ({cause.strerror})" if isinstance(cause, OSError)
                     else "is not a regular file (a FIFO, device, socket or folder)") from None
    except OSError as exc:  # a read error
        raise refuse(f"cannot be read ({exc.strerror or exc})") from None
    if len(data) > MAX_SIDECAR_BYTES:
        raise refuse(f"holds more than {format_size(MAX_SIDECAR_BYTES)}, far more than a list of image names")
    try:
        return json.loads(data.decode("utf-8"))
    except RecursionError:  # '[' * 100000: json recurses once per level
        raise refuse("is not a JSON record (it nests too deeply)") from None
    except ValueError as exc:  # UnicodeDecodeError, JSONDecodeError, an integer of more than 4300 digits
        raise refuse(f"is not a JSON record ({type(exc).__name__}: {str(exc)[:100]})") from None
