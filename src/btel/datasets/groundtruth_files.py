"""Ground-truth files, read as untrusted input (the layouts are listed in
:meth:`btel.datasets.groundtruth.GroundTruth.from_file`).

Every reader checks what a file declares (array shapes, decompressed sizes, rows, indices) against
:mod:`btel.core.limits` before allocating it, refuses anything but regular files (a FIFO would block),
and turns every failure of numpy, scipy, zipfile and csv into a :class:`DataNotFoundError` (or
:class:`ResourceLimitError`) naming the file. MATLAB files: :mod:`btel.datasets.groundtruth_mat`.
"""

from __future__ import annotations

import csv
import io
import os
import re
from array import array as _IntBuffer
from pathlib import Path
from typing import Any

import numpy as np

from ..exceptions import (BTELError, DataNotFoundError, DimensionMismatchError, InvalidDescriptorsError,
                          InvalidParameterError, ResourceLimitError)
from ..core.limits import check_bytes, check_count, check_numpy_file, open_regular, read_regular
from ..descriptors.npy_header import check_npy_header

__all__ = ["read_object_npy", "read_ground_truth", "check_some_positive"]

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
        The file or its elements exceed :mod:`btel.core.limits`.
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
            fh.seek(0)
            if fh.read(1) == b"\x80":  # a bare pickle named .npy
                raise DataNotFoundError(f"{str(path)!r} is a pickle, not an .npy file; btel never unpickles files. "
                                        "Save the ground truth with np.save or np.savez.") from None
            raise DataNotFoundError(f"{str(path)!r} is not an .npy file ({str(exc)[:200]}).") from None
        if not dtype.hasobject:
            raise DataNotFoundError(f"{str(path)!r} holds a plain {dtype} array, not an object array.")
        payload = fh.read()
    try:
        stored_shape, items = parse_object_array(payload)
    except DataNotFoundError as exc:
        raise DataNotFoundError(f"{str(path)!r}: {exc}") from None
    except ResourceLimitError as exc:  # the file's name in the limit's message too
        raise ResourceLimitError(f"{str(path)!r}: {exc}") from None
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
    check_some_positive(gt, f"ground-truth file {str(path)!r}")
    return gt


def check_some_positive(gt: Any, source: str) -> None:
    """Refuse explicit positives in which no query has any: every query would count as wrong, and
    no metric would say anything about the method. Warn when they make more than half the map correct
    for the average query: a guess would then score that well (a radius in the wrong unit, say)."""
    if gt.kind != "positives" or not gt.n_queries:
        return
    if gt.n_without_positives == gt.n_queries:
        raise InvalidParameterError(
            f"{source} gives none of its {gt.n_queries} queries a positive map place, so every query would "
            "count as wrong whatever the method; check that it is the ground truth of these descriptors "
            "(places numbered from 0) and, for positions, the radius.")
    n_map = gt.n_map if gt.n_map else int(gt.indices.max()) + 1
    chance = float(np.mean(np.diff(gt.indptr))) / n_map
    if chance > 0.5:
        import warnings

        warnings.warn(
            f"{source} makes on average {chance:.0%} of the {n_map} map places correct for a query, so a random "
            "guess scores about that recall@1 whatever the method; check that it is the ground truth of these "
            "descriptors and, for positions, the radius (metres, as the positions).", UserWarning, stacklevel=2)


def _read(cls: Any, path: Path, expected: dict[str, int | None]) -> Any:
    suffix = path.suffix.lower()
    if suffix == ".mat":
        from .groundtruth_mat import read_mat_arrays

        return _from_arrays(cls, read_mat_arrays(path), repr(str(path)), expected)
    if suffix in (".csv", ".txt"):
        return _from_csv(cls, path, expected.get("queries"))
    with open_regular(path):
        pass
    try:  # a file cut short is named as such, not as an allocation of many GiB or as "not numpy data"
        check_npy_header(path, "ground-truth file", objects=True)
    except InvalidDescriptorsError as exc:
        raise DataNotFoundError(str(exc)) from None
    check_numpy_file(path, f"ground-truth file {str(path)!r}")
    try:
        loaded = np.load(path, allow_pickle=False)
    except ValueError as exc:
        if suffix == ".npy" and "pickle" in str(exc).lower():
            # VPR-Bench's ground_truth_new.npy: an object array, parsed without unpickling.
            return cls.from_positives(_positives_from_object_array(read_object_npy(path), repr(str(path))))
        if "allow_pickle" in str(exc):  # numpy's advice (load it unsafely) is not btel's
            raise DataNotFoundError(
                f"ground-truth file {str(path)!r} is neither an .npy nor an .npz file (a pickle, or another "
                "format); btel never unpickles files. Give the ground truth as .npy, .npz, .mat or .csv "
                "(`btel evaluate --help`, --ground-truth).") from None
        raise DataNotFoundError(
            f"ground-truth file {str(path)!r} is not valid numpy data ({str(exc)[:200]}); write it again "
            "with np.save or np.savez.") from None
    if isinstance(loaded, np.ndarray):
        if loaded.ndim == 1 and loaded.dtype.kind in "iuf":  # floats must be whole numbers (checked there)
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
    layouts = [name for name, keys in (("indptr+indices", _CSR_KEYS), ("utmDb+utmQ+posDistThr", _UTM_KEYS),
                                       ("query_places", ("query_places",))) if all(k in arrays for k in keys)]
    if len(layouts) > 1:
        raise DataNotFoundError(
            f"{source} holds arrays of {len(layouts)} ground-truth layouts ({', '.join(layouts)}), which may not "
            "agree; keep the arrays of one (np.savez with only those).")
    if all(k in arrays for k in _CSR_KEYS):
        rows = _rows(arrays["indptr"])
        queries = None if rows is None else rows - 1
        _check_counts(source, expected, queries=("indptr (its length − 1)", queries),
                      map_places=("n_map", n_map))
        return cls(indptr=arrays["indptr"], indices=arrays["indices"], n_map=n_map)
    if all(k in arrays for k in _UTM_KEYS):
        _check_counts(source, expected, queries=("utmQ", _rows(arrays["utmQ"])),
                      map_places=("utmDb", _rows(arrays["utmDb"])))
        try:
            return cls.from_utm(arrays["utmDb"], arrays["utmQ"], _scalar(arrays["posDistThr"], "posDistThr", source))
        except (InvalidDescriptorsError, InvalidParameterError, DimensionMismatchError) as exc:
            raise type(exc)(f"{source}: {exc}") from None  # which file holds the bad positions
    if "query_places" in arrays:
        _check_counts(source, expected, queries=("query_places", _rows(arrays["query_places"])),
                      map_places=("n_map", n_map))
        return cls(query_places=arrays["query_places"], n_map=n_map)
    raise DataNotFoundError(
        f"{source} has arrays {sorted(arrays)}, which match no ground-truth layout. Expected "
        "'indptr'+'indices' (positives), 'utmDb'+'utmQ'+'posDistThr' (positions) or "
        "'query_places' (one true place per query).")


def _from_csv(cls: Any, path: Path, n_expected: int | None = None) -> Any:
    text = read_regular(path, f"ground-truth CSV {str(path)!r}", expansion=_CSV_EXPANSION).decode("utf-8-sig")
    queries, places, spans = _IntBuffer("q"), _IntBuffer("q"), _IntBuffer("q")
    with io.StringIO(text, newline="") as fh:
        reader = csv.reader(fh)
        header = [h.strip().lower() for h in next(reader, [])]
        if len(header) < 2 or header[0] != "query" or header[1] not in ("positive", "positives"):
            raise DataNotFoundError(
                f"{str(path)!r} has header {header[:4]}; a ground-truth CSV starts with 'query,positive' (one "
                "pair per line) or 'query,positives' (places separated by spaces or ';').")
        if any(h for h in header[2:]):
            raise DataNotFoundError(
                f"{str(path)!r} has header {header[:4]}: a ground-truth CSV has two columns, 'query,positive' "
                "(one pair per line) or 'query,positives' (places separated by spaces or ';'); drop the "
                f"column{'s' * (len(header) > 3)} after the second (ignored, it would lose places).")
        try:
            for row in reader:
                if not row or not any(cell.strip() for cell in row):
                    continue
                if any(cell.strip() for cell in row[2:]):  # a place after a comma is a third column: never dropped
                    raise DataNotFoundError(
                        f"{str(path)!r} line {reader.line_num}: {row[:4]} has {len(row)} fields; a ground-truth CSV "
                        "has two (query, then its places separated by spaces or ';', not commas).")
                cells = [row[0].strip(), *(row[1].replace(";", " ").split() if len(row) > 1 else [])]
                if not all(_INDEX.fullmatch(c) for c in cells):
                    raise DataNotFoundError(
                        f"{str(path)!r} line {reader.line_num}: {row[:4]} is not a query index and place indices "
                        "(whole numbers 0 ≤ i < 10¹⁸ in ASCII digits).")
                queries.append(int(cells[0]))
                spans.append(len(cells) - 1)
                places.extend(int(c) for c in cells[1:])
        except csv.Error as exc:  # a field past csv's limit (131,072 characters), a NUL in old Pythons
            raise DataNotFoundError(
                f"{str(path)!r} line {reader.line_num}: {exc}. A ground-truth CSV with many positives per query "
                "can list one pair per line instead ('query,positive').") from None
    if not queries:
        raise DataNotFoundError(f"{str(path)!r} lists no query.")
    q = np.frombuffer(queries, dtype=np.int64)
    n_queries = int(q.max()) + 1
    if n_expected is not None and n_queries > n_expected:  # a query past the last one: say so, not "memory"
        _refuse_csv_count(path, q, n_queries, n_expected)
    # indptr, the per-query counts and the CSR copies GroundTruth makes: ~8 int64 per query.
    check_count(n_queries, 64, f"ground-truth CSV {str(path)!r} (query index {n_queries - 1})")
    if n_expected is not None and n_queries != n_expected:
        _refuse_csv_count(path, q, n_queries, n_expected)
    rows = np.repeat(q, np.frombuffer(spans, dtype=np.int64))
    order = np.argsort(rows, kind="stable")
    indptr = np.zeros(n_queries + 1, dtype=np.int64)
    np.cumsum(np.bincount(rows, minlength=n_queries), out=indptr[1:])
    return cls.from_csr(indptr, np.frombuffer(places, dtype=np.int64)[order])


def _refuse_csv_count(path: Path, listed: np.ndarray, n_queries: int, n_expected: int) -> None:
    """Refuse a ground-truth CSV whose query count (its highest query index + 1) is not the number of
    query rows, naming the query rows it has no line for (or the indices past the last query row)."""
    source = f"ground-truth CSV {str(path)!r}"
    if n_queries > n_expected:
        beyond = np.unique(listed[listed >= n_expected])
        raise InvalidParameterError(
            f"{source} lists {_few(beyond, 'query', 'queries')}, but there are only {n_expected} query rows "
            f"(0..{n_expected - 1}); queries are the query descriptors' rows, numbered from 0: give the ground "
            "truth of these descriptors.")
    seen = np.zeros(n_expected, dtype=bool)
    seen[listed] = True
    missing = np.flatnonzero(~seen)
    raise InvalidParameterError(
        f"{source} has no line for {_few(missing, 'query', 'queries')} ({missing.size} of the {n_expected} query "
        f"rows), so it reads as the ground truth of {n_queries} queries (its highest query index + 1). List every "
        f"query row 0..{n_expected - 1}: a query with no positive takes a line with its index and an empty place "
        f"field, e.g. '{int(missing[-1])},' (under either header, 'query,positive' or 'query,positives').")


def _few(indices: np.ndarray, one: str, several: str, shown: int = 5) -> str:
    """``query 3``, ``queries 3, 4, 7`` or ``queries 3, 4, 7, 8, 9 …``: the first few of sorted indices."""
    head = ", ".join(str(int(i)) for i in indices[:shown])
    return f"{one if indices.size == 1 else several} {head}{' …' if indices.size > shown else ''}"
