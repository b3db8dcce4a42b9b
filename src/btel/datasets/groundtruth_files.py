"""Ground-truth files, read as untrusted input (the layouts are listed in
:meth:`btel.datasets.groundtruth.GroundTruth.from_file`).

Every reader checks what a file declares (array shapes, decompressed sizes, rows, indices) against
:mod:`btel.limits` before allocating it, refuses anything but regular files (a FIFO would block),
and turns every failure of numpy, scipy, zipfile and csv into a :class:`DataNotFoundError` (or
:class:`ResourceLimitError`) naming the file.
"""

from __future__ import annotations

import csv
import os
import re
import struct
from array import array as _IntBuffer
from pathlib import Path
from typing import Any

import numpy as np

from ..exceptions import BTELError, DataNotFoundError, InvalidParameterError, ResourceLimitError
from ..limits import check_bytes, check_count, check_numpy_file, memory_limit, open_regular

__all__ = ["read_object_npy", "read_ground_truth"]

_UTM_KEYS = ("utmDb", "utmQ", "posDistThr")
_CSR_KEYS = ("indptr", "indices")
_INDEX = re.compile(r"[0-9]{1,18}")  # ASCII digits only: no '1_0', no other scripts' digits, < 10**18
#: Bytes of btel's memory per byte of CSV (two int64 per pair of at least four characters).
_CSV_EXPANSION = 4


# -- VPR-Bench's object arrays, parsed without unpickling -------------------------------------------
def read_object_npy(path: str | os.PathLike) -> np.ndarray:
    """Read an ``.npy`` holding an object array whose items are integer arrays or integers.

    This is how VPR-Bench stores ground truth (``ground_truth_new.npy``: per query, the indices of
    its correct map images), and ``np.load`` only reads it with ``allow_pickle=True``, which would
    run any code the file names. Here the header is parsed by numpy and the pickled payload by
    :func:`btel.datasets.pickleparse.parse_object_array`, which walks the pickle's opcodes and
    builds the integer arrays itself: nothing in the file is imported or called.

    Returns
    -------
    ndarray, dtype object
        As stored (1-D: one item per query; 2-D: VPR-Bench's rows ``[query index, positives]``);
        every item a 1-D int64 array (an integer item becomes a length-1 array).

    Raises
    ------
    DataNotFoundError
        Not an .npy file, a plain (non-object) array, anything but integer arrays in the pickle.
    ResourceLimitError
        The file or its elements exceed :mod:`btel.limits`.
    """
    from .pickleparse import parse_object_array

    path = Path(path)
    with open_regular(path) as fh:
        check_bytes(os.fstat(fh.fileno()).st_size, f"ground-truth file {str(path)!r}")
        try:
            version = np.lib.format.read_magic(fh)
            read_header = (np.lib.format.read_array_header_1_0 if version == (1, 0)
                           else np.lib.format.read_array_header_2_0)
            shape, _fortran, dtype = read_header(fh)
        except Exception as exc:  # numpy's header parser raises ValueError, SyntaxError, TokenError…
            raise DataNotFoundError(f"{str(path)!r} is not an .npy file ({str(exc)[:200]}).") from None
        if not dtype.hasobject:
            raise DataNotFoundError(f"{str(path)!r} holds a plain {dtype} array, not an object array.")
        payload = fh.read()
    try:
        stored_shape, items = parse_object_array(payload)
    except DataNotFoundError as exc:
        raise DataNotFoundError(f"{str(path)!r}: {exc}") from None
    if stored_shape != tuple(shape):
        raise DataNotFoundError(f"{str(path)!r}: the pickled payload is not the object array its header announces.")
    out = np.empty(len(items), dtype=object)
    for i, item in enumerate(items):
        out[i] = item
    return out.reshape(stored_shape)


def _positives_from_object_array(array: np.ndarray, source: str) -> list[np.ndarray]:
    """Per-query positives from VPR-Bench's layout (rows ``[query index, positives]``) or a 1-D
    object array (item j = positives of query j); items are int64 arrays (:func:`read_object_npy`)."""
    if array.ndim == 2 and array.shape[1] == 2:
        column = list(array[:, 0])
        if any(len(q) != 1 for q in column):
            raise DataNotFoundError(f"{source}: column 0 must hold one query index per row.")
        queries = [int(q[0]) for q in column]
        if sorted(queries) != list(range(len(queries))):
            raise DataNotFoundError(
                f"{source}: the query indices in column 0 are not 0..{len(queries) - 1} once each; cannot tell "
                "which query row each list of positives belongs to.")
        out: list[np.ndarray] = [np.zeros(0, dtype=np.int64)] * len(queries)
        for q, positives in zip(queries, array[:, 1]):
            out[q] = positives
        return out
    if array.ndim == 1:
        return list(array)
    raise DataNotFoundError(
        f"{source}: an object array of shape {array.shape}; expected VPR-Bench's (n_queries, 2) rows "
        "[query index, positives] or a 1-D array of per-query positives.")


# -- every layout -----------------------------------------------------------------------------------
def read_ground_truth(cls: Any, path: str | os.PathLike, *, n_queries: int | None = None,
                      n_map: int | None = None) -> Any:
    """The body of :meth:`GroundTruth.from_file` (``cls`` is the class; ``n_queries`` and
    ``n_map`` the descriptor counts the file must match, when known)."""
    path = Path(path)
    if not path.exists():
        raise DataNotFoundError(f"ground-truth file {str(path)!r} does not exist.")
    if not path.is_file():
        raise DataNotFoundError(f"ground-truth file {str(path)!r} is not a regular file (a folder, FIFO or device).")
    expected = {"queries": n_queries, "map places": n_map}
    try:
        gt = _read(cls, path, expected)
    except BTELError:
        raise
    except Exception as exc:  # untrusted input: zlib.error, tokenize's TokenError, _csv.Error… all mean a bad file
        raise DataNotFoundError(
            f"ground-truth file {str(path)!r} could not be read ({type(exc).__name__}: {str(exc)[:200]}).") from None
    _check_counts(repr(str(path)), expected, queries=("it", gt.n_queries), map_places=("it", gt.n_map))
    return gt


def _read(cls: Any, path: Path, expected: dict[str, int | None]) -> Any:
    suffix = path.suffix.lower()
    if suffix == ".mat":
        return _from_mat(cls, path, expected)
    if suffix in (".csv", ".txt"):
        return _from_csv(cls, path)
    with open_regular(path):
        pass
    check_numpy_file(path, f"ground-truth file {str(path)!r}")
    try:
        loaded = np.load(path, allow_pickle=False)
    except ValueError as exc:
        if suffix == ".npy" and "pickle" in str(exc).lower():
            # VPR-Bench's ground_truth_new.npy: an object array, parsed without unpickling.
            return cls.from_positives(_positives_from_object_array(read_object_npy(path), repr(str(path))))
        raise DataNotFoundError(
            f"ground-truth file {str(path)!r} holds pickled objects or is not numpy data ({str(exc)[:200]}); "
            "btel never loads pickles. Save plain arrays with np.savez.") from None
    if isinstance(loaded, np.ndarray):
        if loaded.ndim == 1 and loaded.dtype.kind in "iu":
            return cls(query_places=loaded)
        raise DataNotFoundError(
            f"{str(path)!r} holds an array of shape {loaded.shape} and dtype {loaded.dtype}; a ground-truth "
            ".npy must be a 1-D integer array of true places (one per query).")
    with loaded as npz:
        arrays = {}
        for name in npz.files:
            try:
                arrays[name] = npz[name]
            except ValueError as exc:
                raise DataNotFoundError(f"array {name!r} in {str(path)!r} is not plain numeric data "
                                        f"({str(exc)[:200]}); btel never loads pickles.") from None
    return _from_arrays(cls, arrays, repr(str(path)), expected)


def _scalar(value: Any, name: str, source: str) -> float:
    arr = np.asarray(value)
    if arr.size != 1 or arr.dtype.kind not in "iuf":
        raise DataNotFoundError(f"{source}: {name} must be one number; got shape {arr.shape} and dtype {arr.dtype}.")
    return float(arr.reshape(-1)[0])


def _check_counts(source: str, expected: dict[str, int | None], **declared: tuple[str, Any]) -> None:
    """Refuse a file whose arrays are for another number of queries or map places than the
    descriptors (``declared``: ``queries=(array name, count)``, ``map_places=…``) before anything
    is computed from them."""
    for key, (array, count) in declared.items():
        what = key.replace("_", " ")
        if expected.get(what) is not None and count is not None and count != expected[what]:
            raise InvalidParameterError(
                f"ground-truth file {source}: {array} is for {count} {what} but there are {expected[what]}; "
                "give the ground truth of these descriptors.")


def _rows(array: np.ndarray) -> int | None:
    return int(array.shape[0]) if np.ndim(array) >= 1 else None


def _from_arrays(cls: Any, arrays: dict[str, np.ndarray], source: str,
                 expected: dict[str, int | None] | None = None) -> Any:
    expected = expected or {}
    n_map = None
    if "n_map" in arrays:
        value = _scalar(arrays["n_map"], "n_map", source)
        if not (value == int(value) if np.isfinite(value) else False) or not 1 <= value < 2**62:
            raise DataNotFoundError(f"{source}: n_map must be a positive whole number; got {value}.")
        n_map = int(value)
    if all(k in arrays for k in _CSR_KEYS):
        rows = _rows(arrays["indptr"])
        queries = None if rows is None else rows - 1
        _check_counts(source, expected, queries=("indptr (its length − 1)", queries),
                      map_places=("n_map", n_map))
        return cls(indptr=arrays["indptr"], indices=arrays["indices"], n_map=n_map)
    if all(k in arrays for k in _UTM_KEYS):
        _check_counts(source, expected, queries=("utmQ", _rows(arrays["utmQ"])),
                      map_places=("utmDb", _rows(arrays["utmDb"])))
        return cls.from_utm(arrays["utmDb"], arrays["utmQ"], _scalar(arrays["posDistThr"], "posDistThr", source))
    if "query_places" in arrays:
        _check_counts(source, expected, queries=("query_places", _rows(arrays["query_places"])),
                      map_places=("n_map", n_map))
        return cls(query_places=arrays["query_places"], n_map=n_map)
    raise DataNotFoundError(
        f"{source} has arrays {sorted(arrays)}, which match no ground-truth layout. Expected "
        "'indptr'+'indices' (positives), 'utmDb'+'utmQ'+'posDistThr' (positions) or "
        "'query_places' (one true place per query).")


def _from_csv(cls: Any, path: Path) -> Any:
    with open_regular(path) as raw:
        check_bytes(os.fstat(raw.fileno()).st_size * _CSV_EXPANSION, f"ground-truth CSV {str(path)!r}")
    queries, places, spans = _IntBuffer("q"), _IntBuffer("q"), _IntBuffer("q")
    with open(path, newline="", encoding="utf-8-sig") as fh:
        reader = csv.reader(fh)
        header = [h.strip().lower() for h in next(reader, [])]
        if len(header) < 2 or header[0] != "query" or header[1] not in ("positive", "positives"):
            raise DataNotFoundError(
                f"{str(path)!r} has header {header[:4]}; a ground-truth CSV starts with 'query,positive' (one "
                "pair per line) or 'query,positives' (places separated by spaces or ';').")
        for row in reader:
            if not row or not any(cell.strip() for cell in row):
                continue
            cells = [row[0].strip(), *(row[1].replace(";", " ").split() if len(row) > 1 else [])]
            if not all(_INDEX.fullmatch(c) for c in cells):
                raise DataNotFoundError(
                    f"{str(path)!r} line {reader.line_num}: {row[:4]} is not a query index and place indices "
                    "(whole numbers 0 ≤ i < 10¹⁸ in ASCII digits).")
            queries.append(int(cells[0]))
            spans.append(len(cells) - 1)
            places.extend(int(c) for c in cells[1:])
    if not queries:
        raise DataNotFoundError(f"{str(path)!r} lists no query.")
    q = np.frombuffer(queries, dtype=np.int64)
    n_queries = int(q.max()) + 1
    # indptr, the per-query counts and the CSR copies GroundTruth makes: ~8 int64 per query.
    check_count(n_queries, 64, f"ground-truth CSV {str(path)!r} (query index {n_queries - 1})")
    rows = np.repeat(q, np.frombuffer(spans, dtype=np.int64))
    order = np.argsort(rows, kind="stable")
    indptr = np.zeros(n_queries + 1, dtype=np.int64)
    np.cumsum(np.bincount(rows, minlength=n_queries), out=indptr[1:])
    return cls.from_csr(indptr, np.frombuffer(places, dtype=np.int64)[order])


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


def _from_mat(cls: Any, path: Path, expected: dict[str, int | None]) -> Any:
    """A MATLAB file, parsed by scipy in a child process: scipy's C reader is not memory-safe on
    damaged files (a SIGSEGV on 304 bytes with one flipped bit), so a crash there must not take
    btel down. The child hands back plain numeric arrays only (an ``.npz`` read without pickles)."""
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
            arrays = {name: npz[name] for name in npz.files}
    return _from_arrays(cls, arrays, source, expected)


#: The child process of :func:`_from_mat`: numpy and scipy only (no btel import: it starts in
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
