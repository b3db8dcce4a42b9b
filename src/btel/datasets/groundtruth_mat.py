"""MATLAB ground-truth files (``.mat`` v5/v7), read as untrusted input.

Before scipy sees a file, its element tags are walked here: unknown data types and sizes past the
end are refused (scipy's C reader segfaulted on such files), and compressed elements are inflated
in 1 MiB pieces, counted against :mod:`btel.core.limits` and never held whole. scipy then parses the
file in a memory-capped child process (:func:`read_mat_arrays`), so that a crash in its reader
cannot take btel down.
"""

from __future__ import annotations

import os
import struct
from pathlib import Path

import numpy as np

from ..exceptions import DataNotFoundError, ResourceLimitError
from ..core.limits import check_bytes, check_numpy_file, memory_limit, open_regular

__all__ = ["read_mat_arrays"]

#: MAT-file v5 data types (miINT8 … miUTF32); scipy's C reader indexes tables by this number.
_MAT5_TYPES = frozenset({1, 2, 3, 4, 5, 6, 7, 9, 12, 13, 14, 15, 16, 17, 18})
_MAT5_MAX_DEPTH = 32


class _MatStream:
    """A MAT-file region read forward: the file's bytes, or a compressed element inflated piece
    by piece (never whole), each inflated byte counted against ``budget`` (shared by the file)."""

    _PIECE = 1 << 20  # most bytes inflated per step
    _FEED = 1 << 16  # compressed bytes given to zlib per step (its unconsumed tail is copied)

    def __init__(self, data: memoryview, source: str, budget: list[int] | None = None) -> None:
        import zlib

        self._input, self._source, self._budget = data, source, budget
        self._inflater = zlib.decompressobj() if budget is not None else None
        self._buffer, self._offset, self.position = b"" if budget is not None else data, 0, 0
        self._fed, self._pending = 0, b""

    def _fill(self, n: int) -> int:
        """Make ``n`` bytes available if the stream has them; return how many are."""
        import zlib

        while len(self._buffer) - self._offset < n and self._inflater is not None and not self._inflater.eof:
            if not self._pending:
                if self._fed >= len(self._input):
                    break  # the compressed data ends before the stream does
                self._pending = self._input[self._fed:self._fed + self._FEED]
                self._fed += self._FEED
            try:
                piece = self._inflater.decompress(self._pending, self._PIECE)
            except zlib.error as exc:
                raise DataNotFoundError(
                    f"{self._source}: a compressed MATLAB element is damaged ({exc}).") from None
            self._pending = self._inflater.unconsumed_tail
            self._budget[0] += len(piece)
            check_bytes(self._budget[0], f"MATLAB file {self._source} (inflated)")
            self._buffer, self._offset = bytes(self._buffer[self._offset:]) + piece, 0
        return min(n, len(self._buffer) - self._offset)

    def read(self, n: int) -> memoryview:
        got = self._fill(n)
        out = memoryview(self._buffer)[self._offset:self._offset + got]
        self._offset += got
        self.position += got
        return out

    def skip(self, n: int) -> int:
        """Pass over ``n`` bytes (inflating them in pieces); return how many there were."""
        done = 0
        while done < n:
            got = len(self.read(min(n - done, self._PIECE)))
            if not got:
                break
            done += got
        return done


def _check_mat5(data: bytes, source: str) -> None:
    """Walk a MATLAB v5 file's element tags and refuse unknown data types or sizes past the end
    before scipy reads it: scipy's C reader crashed the process (SIGSEGV) on a 304-byte file with
    one flipped bit in a type. Compressed elements are inflated in 1 MiB pieces, counted against
    the memory limit and never held whole (a 256 MB inflation peaked at 844 MB before)."""
    if len(data) < 128 or data[126:128] not in (b"IM", b"MI"):
        raise DataNotFoundError(f"{source} is not a MATLAB v5/v7 file (v4 and v7.3 files are not read); "
                                "re-save it with -v7 or convert it to .npz.")
    order = "<" if data[126:128] == b"IM" else ">"
    budget = [0]

    def damaged(what: str, stream: _MatStream) -> DataNotFoundError:
        return DataNotFoundError(f"{source}: {what} at byte {stream.position}; the file is damaged.")

    def walk(stream: _MatStream, end: int | None, depth: int) -> None:
        """The elements of ``stream`` up to byte ``end`` (None: to its end)."""
        if depth > _MAT5_MAX_DEPTH:
            raise DataNotFoundError(f"{source}: MATLAB elements nested more than {_MAT5_MAX_DEPTH} deep.")
        while end is None or stream.position + 8 <= end:
            tag = stream.read(8)
            if len(tag) < 8:
                if end is not None:
                    raise damaged("a MATLAB element runs past the end of its data", stream)
                return
            mdtype, nbytes = struct.unpack(order + "II", tag)
            if mdtype >> 16:  # small data element: type and size in one word, data in the next
                mdtype, nbytes = mdtype & 0xFFFF, mdtype >> 16
                if nbytes > 4:
                    raise DataNotFoundError(f"{source}: a small MATLAB element claims {nbytes} bytes.")
                if mdtype not in _MAT5_TYPES:
                    raise damaged(f"unknown MATLAB data type {mdtype}", stream)
                continue
            if mdtype not in _MAT5_TYPES:
                raise damaged(f"unknown MATLAB data type {mdtype}", stream)
            body_end = stream.position + nbytes
            if end is not None and body_end > end:
                raise damaged("a MATLAB element runs past the end of its data", stream)
            if mdtype == 15:
                if stream._inflater is not None:
                    raise damaged("a compressed MATLAB element inside a compressed one", stream)
                body = stream.read(nbytes)
                if len(body) < nbytes:
                    raise damaged("a MATLAB element runs past the end of its data", stream)
                walk(_MatStream(body, source, budget), None, depth + 1)
                continue
            if mdtype == 14:
                walk(stream, body_end, depth + 1)
                stream.skip(body_end - stream.position)
            elif stream.skip(nbytes) < nbytes:
                raise damaged("a MATLAB element runs past the end of its data", stream)
            stream.skip(-nbytes % 8)  # padding (may be cut at the end)

    walk(_MatStream(memoryview(data)[128:], source), len(data) - 128, 0)


def read_mat_arrays(path: Path) -> dict[str, np.ndarray]:
    """The numeric arrays of a MATLAB ground-truth file, parsed by scipy in a child process.

    The file is walked first (:func:`_check_mat5`). scipy's C reader is not memory-safe on damaged
    files (a SIGSEGV on 304 bytes with one flipped bit), so a crash there must not take btel down;
    the child hands back plain numeric arrays only (an ``.npz`` read without pickles). NetVLAD's
    ``dbStruct`` comes back as top-level ``utmDb``/``utmQ`` (one position per row) and
    ``posDistThr``.

    Raises
    ------
    DataNotFoundError
        Not a MATLAB v5/v7 file, damaged, or not numeric.
    ResourceLimitError
        The file, its inflation or its declared arrays exceed :mod:`btel.core.limits`.
    """
    import subprocess
    import sys
    import tempfile

    source = repr(str(path))
    with open_regular(path) as fh:
        check_bytes(os.fstat(fh.fileno()).st_size, f"MATLAB ground-truth file {source}")
        _check_mat5(fh.read(), source)
    limit = memory_limit()

    def cap_memory() -> None:  # the child may use the limit plus the interpreter's own share
        import resource

        cap = limit * 3 + (1 << 30)
        resource.setrlimit(resource.RLIMIT_AS, (cap, cap))

    with tempfile.TemporaryDirectory(prefix="btel-mat-") as tmp:
        out = Path(tmp) / "arrays.npz"
        try:
            proc = subprocess.run(
                [sys.executable, "-I", "-c", _MAT_CHILD, str(path), str(out), str(limit)], capture_output=True,
                text=True, timeout=300, preexec_fn=cap_memory if os.name == "posix" else None)
        except subprocess.TimeoutExpired:
            raise DataNotFoundError(f"{source}: scipy.io.loadmat did not finish within 300 s; the file is "
                                    "damaged or hostile.") from None
        message = (proc.stderr.strip().splitlines() or [""])[-1][:400]
        if proc.returncode == 4:
            raise ResourceLimitError(message)
        if proc.returncode == 3:
            raise DataNotFoundError(message)
        if proc.returncode != 0 or not out.is_file():
            raise DataNotFoundError(
                f"{source} could not be read by scipy.io.loadmat (its reader ended with status {proc.returncode}); "
                "the file is damaged. MATLAB v7.3 files are HDF5: re-save with -v7 or convert to .npz.")
        check_numpy_file(out, f"MATLAB ground-truth file {source}")
        with np.load(out, allow_pickle=False) as npz:
            return {name: npz[name] for name in npz.files}


#: The child process of :func:`read_mat_arrays`: numpy and scipy only (no btel import: it starts in
#: ~0.5 s), ``argv`` = path, output .npz, memory limit. Exit 3 with a message on stderr for a
#: bad file, 4 for the memory limit.
_MAT_CHILD = r"""
import sys
import numpy as np
import scipy.io

path, out, limit = sys.argv[1], sys.argv[2], int(sys.argv[3])
source = repr(path)
KEYS = ("utmDb", "utmQ", "posDistThr")


def fail(code, message):
    sys.stderr.write(message + "\n")
    sys.exit(code)


try:
    declared = scipy.io.whosmat(path)
except Exception as exc:
    fail(3, f"{source} could not be read by scipy.io.loadmat ({type(exc).__name__}: {str(exc)[:200]}). "
            "MATLAB v7.3 files are HDF5: re-save with -v7 or convert to .npz.")
total = sum(float(np.prod([float(s) for s in shape])) * 8 for _, shape, _ in declared)
if not total <= limit:
    fail(4, f"MATLAB ground-truth file {source} declares {total / 2**20:.1f} MiB of arrays, over btel's memory "
            f"limit of {limit / 2**20:.1f} MiB; if the input is genuine, raise the limit with BTEL_MEMORY_LIMIT "
            "(e.g. BTEL_MEMORY_LIMIT=4G).")
try:
    mat = scipy.io.loadmat(path)
    if "dbStruct" in mat and not all(k in mat for k in KEYS):
        struct_ = mat["dbStruct"]
        names = struct_.dtype.names or ()
        if not all(k in names for k in KEYS) or struct_.size != 1:
            fail(3, f"{source} has a dbStruct with fields {list(names)[:10]}; expected one struct with NetVLAD's "
                    "utmDb, utmQ and posDistThr.")
        fields = {k: np.asarray(struct_[k].reshape(-1)[0]) for k in KEYS}
        # NetVLAD stores positions as 2 x n (one column per image).
        arrays = {"utmDb": fields["utmDb"].T, "utmQ": fields["utmQ"].T, "posDistThr": fields["posDistThr"]}
    else:
        arrays = {k: np.asarray(v) for k, v in mat.items() if not k.startswith("__")}
        for key in ("query_places", "indptr", "indices"):  # MATLAB vectors are 1 x n or n x 1
            if key in arrays:
                arrays[key] = arrays[key].ravel()
    plain = {k: v for k, v in arrays.items() if v.dtype.kind in "biuf" and not v.dtype.hasobject}
    for key in (*KEYS, "indptr", "indices", "query_places", "n_map"):
        if key in arrays and key not in plain:
            fail(3, f"{source}: {key} holds {arrays[key].dtype} values, not numbers.")
    np.savez(out, **plain)
except SystemExit:
    raise
except BaseException as exc:
    fail(3, f"{source} could not be read by scipy.io.loadmat ({type(exc).__name__}: {str(exc)[:200]}).")
"""
