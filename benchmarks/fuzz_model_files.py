"""Fuzz ``btel.load`` with damaged, edited and crafted model files (issue #13).

A model file is untrusted input. This harness fits a small model of every registered method (and
a few variants that store more arrays: regions, a whitening front end, offset codes, a row →
place table, a projection), then derives seeded cases from their files by one mutation each:

- ``bitflip``     — 1–8 random bits flipped anywhere in the file;
- ``truncate``    — the file cut at a random length;
- ``bytes``       — random bytes overwritten, a span deleted or duplicated;
- ``header``      — one edit of the JSON header, written back into a valid file: wrong types,
  huge / negative / fractional / NaN / 1e400 numbers, 5000-digit integers, nesting 10⁵ deep,
  unknown model names, nested estimator dicts for OPQ's ``pq``, removed or unknown keys,
  runtime settings (``n_jobs``), small ±1 / ×2 edits of the state, non-UTF-8 or cut JSON;
- ``array``       — one array changed: shape (rows dropped or added, transposed, 3-D, empty),
  dtype (float16/64, ints, bool, complex, unicode, bytes), values (NaN, ±inf, 1e38, huge or
  out-of-range indices, shuffled region starts), removed, renamed or an extra array;
- ``combo``       — two or three header and array edits on top of each other;
- ``zip``         — the container: deflated members (one a decompression bomb), duplicate or
  non-``.npy`` members, the encryption flag, declared sizes edited, ``.npy`` headers edited
  (declared shape 10¹², object / complex / unicode dtypes, Fortran order, a flipped byte, a
  5000-digit dimension, an unknown format version).

Each case runs in a worker process: ``btel.load``, then ``predict``, ``rank(Q, 3)``,
``predict_sequence(Q, 'hmm')`` and one streamed query on a few queries. A case **passes** when
``load`` raises :class:`~btel.exceptions.ModelFileError`, or when it loads and every answer is an
int64 place in [0, N) (a project error from a query on a loaded model — e.g. its dimension was
edited — is counted apart and passes too). It **fails** on any other exception, an answer outside
[0, N), more than 2 s of work, no answer within the hard timeout (the worker is killed: a hang),
or the worker's death (a segfault or abort is counted, not fatal).

Run (the documented command; writes ``benchmarks/results/fuzz_model_files.json``)::

    python benchmarks/fuzz_model_files.py --cases 50000 --seed 0 --workers 2

``--case ID`` reruns one case in this process with its traceback. The tests run a short seeded
run of the same cases (``tests/test_fuzz_model_files.py``).
"""

from __future__ import annotations

import argparse
import io
import json
import os
import resource
import select
import struct
import subprocess
import sys
import tempfile
import time
import traceback
import warnings
import zipfile
from collections import Counter, defaultdict
from pathlib import Path
from typing import Any, Callable

import numpy as np

HERE = Path(__file__).resolve().parent
HEADER_KEY = "__btel_header__"
#: Work a case may take before it counts as a hang (seconds, measured in the worker).
SLOW_SECONDS = 2.0
#: A worker that does not answer within this is killed and the case counts as a hang.
HARD_TIMEOUT = 30.0
N_QUERIES = 6

KINDS = ("bitflip", "truncate", "bytes", "header", "array", "zip", "combo")
#: Relative frequency of each kind (the structured edits reach deeper than random bytes, which the
#: zip CRC mostly catches).
KIND_WEIGHTS = (1, 1, 1, 3, 3, 2, 2)


# ----------------------------------------------------------------------------------- fixtures
def fixture_specs() -> dict[str, tuple[str, dict[str, Any], bool]]:
    """Fixture name → (registered method, parameters, fit with place labels of two traverses)."""
    from btel.methods import METHODS

    specs: dict[str, tuple[str, dict[str, Any], bool]] = {name: (name, {}, False) for name in METHODS}
    specs.update({
        "btel-c-whiten": ("btel-c", {"whiten": 8}, False),
        "btel-c-offset": ("btel-c", {"code_copies": 2, "block_size": 2, "dtype": "float16"}, False),
        "btel-c-soft-all": ("btel-c", {"decode": "soft", "feature_ratio": 1.0}, False),
        "btel-r3": ("btel-c", {"n_regions": 3}, False),
        "btel-f-r2": ("btel-f", {"n_regions": 2}, False),
        "ryth-crt": ("ryth", {"decode": "crt", "n_periods": 2}, False),
        "bruteforce-places": ("bruteforce", {}, True),
        "pq-pca": ("pq", {"pca_dim": 8}, False),
        "itq-places": ("itq", {}, True),
        "seqslam-delta": ("seqslam", {"delta": 2, "ds": 4}, False),
        "btel-codes-random-8bit": ("btel-codes", {"code": "random", "weight_bits": 8}, False),
        "btel-codes-places": ("btel-codes", {"code": "blocks", "weight_bits": 32}, True),
    })
    return specs


def build_fixtures(folder: Path, n_places: int = 64, dim: int = 16) -> dict[str, dict[str, Any]]:
    """Fit every fixture, save its model and queries in ``folder``; name → {path, queries, n_places}."""
    from btel.datasets import synthetic_route
    from btel.methods import make_method

    route = synthetic_route(n_places, dim, n_traverses=2, n_regions=3, seed=7)
    traverses = np.concatenate([route.map, route.map + 0.01 * np.random.default_rng(1).standard_normal(
        route.map.shape).astype(np.float32)])
    labels = np.concatenate([np.arange(n_places), np.arange(n_places)])
    queries = np.ascontiguousarray(route.queries[:N_QUERIES], dtype=np.float32)
    np.save(folder / "queries.npy", queries)
    out = {}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for name, (method, params, with_places) in fixture_specs().items():
            extra = {"progress": False} if "progress" in make_method(method).get_params() else {}
            model = make_method(method, **params, **extra)
            model.fit(traverses, labels) if with_places else model.fit(route.map)
            path = folder / f"{name}.npz"
            model.save(path)
            out[name] = {"path": str(path), "n_places": n_places}
    return out


# ----------------------------------------------------------------------------------- containers
def read_members(data: bytes) -> list[tuple[str, bytes]]:
    """(name, raw .npy bytes) of every member of a valid model file, in order."""
    with zipfile.ZipFile(io.BytesIO(data)) as archive:
        return [(info.filename, archive.read(info)) for info in archive.infolist()]


def write_members(members: list[tuple[str, bytes]], compress: dict[int, int] | None = None) -> bytes:
    """A zip of the members (stored, or the zip method given per member index); duplicates allowed."""
    buffer = io.BytesIO()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # "Duplicate name"
        with zipfile.ZipFile(buffer, "w") as archive:
            for i, (name, raw) in enumerate(members):
                info = zipfile.ZipInfo(name, date_time=(1980, 1, 1, 0, 0, 0))
                info.compress_type = (compress or {}).get(i, zipfile.ZIP_STORED)
                archive.writestr(info, raw)
    return buffer.getvalue()


def npy_bytes(array: np.ndarray) -> bytes:
    buffer = io.BytesIO()
    np.lib.format.write_array(buffer, np.asarray(array), allow_pickle=False)
    return buffer.getvalue()


def npy_parse(raw: bytes) -> np.ndarray:
    return np.lib.format.read_array(io.BytesIO(raw), allow_pickle=False)


def header_of(members: list[tuple[str, bytes]]) -> tuple[int, dict[str, Any]]:
    for i, (name, raw) in enumerate(members):
        if name == HEADER_KEY + ".npy":
            return i, json.loads(npy_parse(raw).tobytes().decode("utf-8"))
    raise KeyError(HEADER_KEY)


def with_header_text(members: list[tuple[str, bytes]], text: bytes) -> bytes:
    index, _ = header_of(members)
    edited = list(members)
    edited[index] = (members[index][0], npy_bytes(np.frombuffer(text, dtype=np.uint8)))
    return write_members(edited)


# ----------------------------------------------------------------------------------- mutations
Mutation = Callable[[np.random.Generator, bytes], tuple[bytes, str]]


def mutate_bitflip(rng: np.random.Generator, data: bytes) -> tuple[bytes, str]:
    out = bytearray(data)
    n = int(rng.integers(1, 9))
    where = rng.integers(0, len(out) * 8, size=n)
    for bit in where.tolist():
        out[bit // 8] ^= 1 << (bit % 8)
    return bytes(out), f"{n} bit(s) flipped at {sorted(where.tolist())[:4]}"


def mutate_truncate(rng: np.random.Generator, data: bytes) -> tuple[bytes, str]:
    cut = int(rng.integers(0, len(data)))
    return data[:cut], f"cut to {cut} of {len(data)} B"


def mutate_bytes(rng: np.random.Generator, data: bytes) -> tuple[bytes, str]:
    out = bytearray(data)
    op = rng.integers(3)
    start = int(rng.integers(0, len(out)))
    span = int(rng.integers(1, 64))
    if op == 0:
        out[start : start + span] = rng.integers(0, 256, size=len(out[start : start + span]), dtype=np.uint8).tobytes()
        return bytes(out), f"{span} random bytes at {start}"
    if op == 1:
        del out[start : start + span]
        return bytes(out), f"{span} bytes deleted at {start}"
    out[start:start] = out[start : start + span]
    return bytes(out), f"{span} bytes duplicated at {start}"


#: Placeholder replaced in the JSON text by a literal json.dumps cannot write.
_RAW = "__raw_literal__"
_RAW_LITERALS = ["NaN", "Infinity", "-Infinity", "1e400", "-1e400", "9" * 5000, "1" + "0" * 30,
                 "[" * 100_000 + "]" * 100_000, "{\"a\":" * 50_000 + "1" + "}" * 50_000, "1e-400", "-0"]


def _header_values(rng: np.random.Generator, old: Any) -> tuple[Any, str]:
    """A replacement value for a header field (or a raw literal, returned as _RAW + index)."""
    pool: list[Any] = [None, True, False, "", "x" * 10, "auto", [], [1, 2], {}, {"a": 1}, 0, -1, -3, 1, 2, 3,
                       10**3, 10**6, 10**9, 33_571_696, 2**31, 2**32 + 1, 2**40, 2**63, 2**64, 10**20,
                       0.5, -0.5, 1e-300, 1e300, 3.7, "float16", "float64", "complex64", "<U3", "|O",
                       {"estimator": "PQLocalizer", "params": {}},
                       {"estimator": "PQLocalizer", "params": {"nbits": 100}},
                       {"estimator": "PQLocalizer", "params": {"n_jobs": 10**9}},
                       {"estimator": "OPQLocalizer", "params": {"pq": {"estimator": "OPQLocalizer", "params": {}}}},
                       {"estimator": "BruteForceNN", "params": {}}, {"estimator": ["x"], "params": []},
                       "BTELocalizer", "RYTHLocalizer", "PQLocalizer", "OPQLocalizer", "NotAModel"]
    choice = rng.integers(4)
    if choice == 0 and isinstance(old, (int, float)) and not isinstance(old, bool):
        factor = rng.choice([-1, 0, 2, 0.5, 1.5])
        step = int(rng.choice([-2, -1, 1, 2]))
        with np.errstate(all="ignore"):  # an earlier edit may have left 1e300 here
            value = old + step if isinstance(old, int) and rng.random() < 0.5 else \
                (type(old)(old * factor) if np.isfinite(old * factor) else old)
        return value, f"{old!r} → {value!r}"
    if choice == 1:
        i = int(rng.integers(len(_RAW_LITERALS)))
        return f"{_RAW}{i}", f"raw {_RAW_LITERALS[i][:20]}…({len(_RAW_LITERALS[i])} chars)"
    value = pool[int(rng.integers(len(pool)))]
    return value, f"{str(old)[:30]} → {str(value)[:60]}"


def _paths(value: Any, prefix: tuple = ()) -> list[tuple]:
    """Every key path into the header's objects and lists (the header itself excluded)."""
    out = []
    if isinstance(value, dict):
        for k, v in value.items():
            out.append(prefix + (k,))
            out.extend(_paths(v, prefix + (k,)))
    elif isinstance(value, list):
        for i, v in enumerate(value):
            out.append(prefix + (i,))
            out.extend(_paths(v, prefix + (i,)))
    return out


def mutate_header(rng: np.random.Generator, data: bytes) -> tuple[bytes, str]:
    members = read_members(data)
    _, header = header_of(members)
    op = rng.integers(10)
    if op == 0:  # the raw bytes of the JSON
        text = json.dumps(header).encode()
        sub = rng.integers(3)
        if sub == 0:
            cut = int(rng.integers(0, len(text)))
            return with_header_text(members, text[:cut]), f"header JSON cut at {cut}"
        if sub == 1:
            pos = int(rng.integers(0, len(text)))
            return with_header_text(members, text[:pos] + b"\xff\xfe" + text[pos:]), f"non-UTF-8 bytes at {pos}"
        return with_header_text(members, text.replace(b'"', b"'", 1)), "single quote"
    if op == 1:  # runtime settings and unknown keys
        target = header.setdefault("params", {}) if isinstance(header.get("params"), dict) else header
        key = str(rng.choice(["n_jobs", "backend", "scheduler", "progress", "bogus", "__class__"]))
        value, what = _header_values(rng, target.get(key))
        if key == "n_jobs" and rng.random() < 0.5:
            value, what = int(rng.choice([10**9, 33_571_696, 0, -5, 4096])), "n_jobs"
        target[key] = value
        description = f"params.{key}: {what}"
    else:
        paths = _paths(header)
        path = paths[int(rng.integers(len(paths)))]
        parent = header
        for k in path[:-1]:
            parent = parent[k]
        old = parent[path[-1]]
        if rng.random() < 0.1:
            if isinstance(parent, dict):
                del parent[path[-1]]
            else:
                parent.pop(path[-1])
            description = f"{'.'.join(map(str, path))} removed"
        else:
            value, what = _header_values(rng, old)
            parent[path[-1]] = value
            description = f"{'.'.join(map(str, path))}: {what}"
    text = json.dumps(header)
    for i, literal in enumerate(_RAW_LITERALS):
        text = text.replace(json.dumps(f"{_RAW}{i}"), literal)
    return with_header_text(members, text.encode()), description


def _array_edits(rng: np.random.Generator, a: np.ndarray) -> tuple[np.ndarray, str]:
    op = int(rng.integers(14))
    if op == 0 and a.ndim >= 1 and a.shape[0] > 0:
        return a[:-1], "last row dropped"
    if op == 1 and a.ndim >= 1:
        return np.concatenate([a, a[:1]]) if a.shape[0] else a, "a row added"
    if op == 2:
        return np.ascontiguousarray(a.T), "transposed"
    if op == 3:
        return a[None], "made 3-D" if a.ndim == 2 else "one more axis"
    if op == 4:
        return a.reshape(-1), "flattened"
    if op == 5:
        return a[:0], "emptied"
    if op == 6:
        dtype = str(rng.choice(["float16", "float64", "int8", "int64", "uint8", "uint64", "bool", "complex64",
                                "<U3", "S2", "float32", "uint16", "uint32"]))
        try:
            return a.astype(dtype), f"as {dtype}"
        except (ValueError, TypeError, OverflowError):
            return a, "unchanged"
    if op == 7 and a.dtype.kind == "f" and a.size:
        b = a.copy()
        b.flat[int(rng.integers(a.size))] = rng.choice([np.nan, np.inf, -np.inf, 3e38, -3e38, 1e20])
        return b, "one value NaN/inf/huge"
    if op == 8 and a.dtype.kind in "iu" and a.size:
        b = a.copy()
        info = np.iinfo(a.dtype)
        b.flat[int(rng.integers(a.size))] = rng.choice([info.max, info.min, 0, info.max // 2 + 1])
        return b, "one index extreme"
    if op == 9 and a.size:
        b = a.copy()
        rng.shuffle(b.reshape(-1))
        return b, "values shuffled"
    if op == 10 and a.dtype.kind in "iu" and a.size:
        return (a + np.asarray(int(rng.integers(1, 64))).astype(a.dtype)).astype(a.dtype), "indices shifted up"
    if op == 11 and a.size:
        return np.zeros_like(a), "zeroed"
    if op == 12 and a.dtype.kind == "f" and a.size:
        return (a * np.float32(rng.choice([1e30, -1, 1e-30]))).astype(a.dtype), "scaled"
    return np.repeat(a, 2, axis=-1) if a.ndim else a, "columns doubled"


def mutate_array(rng: np.random.Generator, data: bytes) -> tuple[bytes, str]:
    members = read_members(data)
    arrays = [i for i, (name, _) in enumerate(members) if name != HEADER_KEY + ".npy"]
    op = rng.integers(10)
    if op == 0 or not arrays:  # an extra array
        members.append((str(rng.choice(["extra.npy", "weights.npy", "bias.npy", "descriptors.npy"])),
                        npy_bytes(np.zeros(3, dtype=np.float32))))
        return write_members(members), f"extra array {members[-1][0]}"
    i = arrays[int(rng.integers(len(arrays)))]
    name, raw = members[i]
    if op == 1:
        del members[i]
        return write_members(members), f"{name} removed"
    if op == 2:
        members[i] = ("renamed.npy", raw)
        return write_members(members), f"{name} renamed"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        edited, what = _array_edits(rng, npy_parse(raw))
    members[i] = (name, npy_bytes(edited))
    return write_members(members), f"{name}: {what}"


def _npy_with_header(array: np.ndarray, header_text: str, version: bytes = b"\x01\x00", payload: bytes | None = None
                     ) -> bytes:
    text = header_text.encode("latin1")
    pad = 64 - (10 + len(text) + 1) % 64
    text = text + b" " * pad + b"\n"
    data = array.tobytes() if payload is None else payload
    if version == b"\x01\x00" and len(text) < 65536:
        return b"\x93NUMPY" + version + struct.pack("<H", len(text)) + text + data
    return b"\x93NUMPY" + version + struct.pack("<I", len(text)) + text + data


def mutate_zip(rng: np.random.Generator, data: bytes) -> tuple[bytes, str]:
    members = read_members(data)
    arrays = [i for i, (name, _) in enumerate(members) if name != HEADER_KEY + ".npy"] or [0]
    i = arrays[int(rng.integers(len(arrays)))]
    name, raw = members[i]
    op = int(rng.integers(12))
    if op == 0:
        return write_members(members, {j: zipfile.ZIP_DEFLATED for j in range(len(members))}), "all deflated"
    if op == 1:  # a decompression bomb: 64 MB of zeros declared as an array
        bomb = np.lib.format.header_data_from_array_1_0(np.zeros(1, np.float32))
        bomb["shape"] = (16_000_000,)
        members.append(("bomb.npy", _npy_with_header(np.zeros(0), repr(bomb), payload=bytes(64_000_000))))
        return write_members(members, {len(members) - 1: zipfile.ZIP_DEFLATED}), "deflated 64 MB bomb"
    if op == 2:
        members.append((name, raw))
        return write_members(members), f"{name} twice"
    if op == 3:
        members.append((str(rng.choice(["notes.txt", "x.pkl", "dir/", "a.npy/b"])), b"hello"))
        return write_members(members), f"non-array member {members[-1][0]}"
    if op in (4, 5):  # encryption flag or declared sizes in the central directory / local headers
        out = bytearray(write_members(members))
        central = [k for k in range(len(out) - 4) if out[k : k + 4] == b"PK\x01\x02"]
        k = central[int(rng.integers(len(central)))]
        if op == 4:
            out[k + 8] |= 1
            return bytes(out), "encryption flag set"
        value = int(rng.choice([0, 1, 2**31, 2**32 - 1, len(out) * 2]))
        field = int(rng.choice([20, 24]))
        out[k + field : k + field + 4] = struct.pack("<I", value)
        return bytes(out), f"declared size {value} (offset {field})"
    array = npy_parse(raw)
    fields = np.lib.format.header_data_from_array_1_0(array)
    if op == 6:
        fields["shape"] = tuple([10**12] + list(array.shape[1:])) if rng.random() < 0.5 else (10**6, 10**6)
        what = f"declared shape {fields['shape']}"
    elif op == 7:
        fields["descr"] = str(rng.choice(["|O", "<c8", "<U2", "|S4", "<M8[s]", "|V4", "[('a', '<f4')]", ">f4", "<f2"]))
        what = f"declared dtype {fields['descr']}"
        if fields["descr"].startswith("["):
            text = repr(fields).replace(repr(fields["descr"]), fields["descr"])
            members[i] = (name, _npy_with_header(array, text))
            return write_members(members), what
    elif op == 8:
        fields["fortran_order"] = not fields["fortran_order"]
        what = "fortran order flipped"
    elif op == 9:
        text = repr(fields)
        pos = int(rng.integers(len(text)))
        text = text[:pos] + chr(int(rng.integers(32, 127))) + text[pos + 1 :]
        members[i] = (name, _npy_with_header(array, text))
        return write_members(members), f"npy header byte {pos} changed"
    elif op == 10:
        text = repr(fields).replace(repr(fields["shape"]), "(" + "9" * 5000 + ",)")
        members[i] = (name, _npy_with_header(array, text))
        return write_members(members), "5000-digit dimension"
    else:
        version = bytes([int(rng.choice([0, 3, 9])), 0])
        members[i] = (name, _npy_with_header(array, repr(fields), version=version))
        return write_members(members), f"npy version {version[0]}"
    members[i] = (name, _npy_with_header(array, repr(fields)))
    return write_members(members), what


def mutate_combo(rng: np.random.Generator, data: bytes) -> tuple[bytes, str]:
    """Two or three header and array edits on top of each other (files edited in more than one place)."""
    steps = []
    for _ in range(int(rng.integers(2, 4))):
        mutation = mutate_header if rng.random() < 0.5 else mutate_array
        try:
            data, what = mutation(rng, data)
        except Exception:  # an earlier edit left nothing this one can parse (e.g. a cut header): stop here
            break
        steps.append(what)
    return data, " + ".join(steps)


MUTATIONS: dict[str, Mutation] = {"bitflip": mutate_bitflip, "truncate": mutate_truncate, "bytes": mutate_bytes,
                                  "header": mutate_header, "array": mutate_array, "zip": mutate_zip,
                                  "combo": mutate_combo}


def make_case(seed: int, case_id: int, fixtures: list[str], originals: dict[str, bytes]
              ) -> tuple[str, str, bytes, str]:
    """(fixture, kind, mutated file bytes, description) of case ``case_id`` (deterministic)."""
    rng = np.random.default_rng([seed, case_id])
    fixture = fixtures[int(rng.integers(len(fixtures)))]
    weights = np.asarray(KIND_WEIGHTS, dtype=float)
    kind = KINDS[int(rng.choice(len(KINDS), p=weights / weights.sum()))]
    data, description = MUTATIONS[kind](rng, originals[fixture])
    return fixture, kind, data, description


# ----------------------------------------------------------------------------------- one case
def run_case(path: str, queries: np.ndarray) -> dict[str, Any]:
    """Load the file and query it; the outcome (module docstring) and the work's duration."""
    import btel
    from btel.exceptions import BTELError, ModelFileError

    start = time.perf_counter()
    result: dict[str, Any] = {}
    try:
        try:
            model = btel.load(path)
        except ModelFileError as exc:
            result.update(outcome="rejected", error=str(exc)[:200])
            return result
        n = int(model.n_places_)
        answers = {}
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                answers["predict"] = model.predict(queries)
                answers["rank"] = model.rank(queries, 3)
                answers["hmm"] = model.predict_sequence(queries, "hmm")
                answers["stream"] = model.stream().search(queries[0], 2)[1]
        except BTELError as exc:
            result.update(outcome="loaded_query_refused", error=f"{type(exc).__name__}: {str(exc)[:200]}")
            return result
        for what, places in answers.items():
            places = np.asarray(places)
            if places.dtype != np.int64 or places.size == 0 or places.min() < 0 or places.max() >= n:
                result.update(outcome="out_of_range",
                              error=f"{what}: dtype {places.dtype}, range [{places.min()}, {places.max()}], N = {n}")
                return result
        result.update(outcome="loaded")
        return result
    except Exception as exc:  # the failures this harness looks for
        result.update(outcome="exception", error=f"{type(exc).__name__}: {str(exc)[:300]}",
                      traceback=traceback.format_exc()[-1500:])
        return result
    finally:
        result["seconds"] = time.perf_counter() - start
        if result.get("outcome") in ("rejected", "loaded", "loaded_query_refused") and result["seconds"] > SLOW_SECONDS:
            result["outcome"] = "slow"


def worker_main() -> None:
    """Answer cases from stdin (one JSON line each) on a private copy of stdout (one JSON line each)."""
    out = os.fdopen(os.dup(1), "w", buffering=1)
    os.dup2(2, 1)  # anything else written to stdout (C code included) goes to stderr
    sys.stdout = sys.stderr
    import btel  # noqa: F401  (import before the first case: its time is not the case's)
    import btel.methods.registry  # noqa: F401  (btel.load and every method: btel imports them lazily)

    queries = np.load(sys.argv[sys.argv.index("--queries") + 1])
    for line in sys.stdin:
        task = json.loads(line)
        result = run_case(task["path"], queries)
        result["id"] = task["id"]
        result["max_rss_kb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
        out.write(json.dumps(result) + "\n")


# ----------------------------------------------------------------------------------- the pool
class Worker:
    """A worker process answering one case at a time (killed and replaced on a hang or a death)."""

    def __init__(self, queries_path: Path) -> None:
        self.proc = subprocess.Popen(
            [sys.executable, str(Path(__file__).resolve()), "--worker", "--queries", str(queries_path)],
            stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True, bufsize=1,
            env={**os.environ, "OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"},
        )
        self.task: dict[str, Any] | None = None
        self.deadline = 0.0
        self.buffer = ""

    def send(self, task: dict[str, Any], timeout: float) -> None:
        self.task, self.deadline = task, time.monotonic() + timeout
        self.proc.stdin.write(json.dumps({"id": task["id"], "path": task["path"]}) + "\n")
        self.proc.stdin.flush()

    def read_result(self) -> dict[str, Any] | None:
        """The finished case's result, None while it is not complete; raises EOFError if the worker died."""
        chunk = os.read(self.proc.stdout.fileno(), 1 << 16).decode()
        if not chunk:
            raise EOFError
        self.buffer += chunk
        if "\n" not in self.buffer:
            return None
        line, self.buffer = self.buffer.split("\n", 1)
        return json.loads(line)

    def kill(self) -> int | None:
        self.proc.kill()
        return self.proc.wait()

    def close(self) -> None:
        try:
            self.proc.stdin.close()
        except OSError:
            pass
        try:
            self.proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            self.kill()


def run_cases(n_cases: int, seed: int, *, workers: int = 2, first_case: int = 0, hard_timeout: float = HARD_TIMEOUT,
              progress: bool = False, folder: Path | None = None) -> dict[str, Any]:
    """Run cases first_case … first_case + n_cases − 1; return the summary (see :func:`summarise`)."""
    with tempfile.TemporaryDirectory(prefix="btel-fuzz-", dir=folder) as tmp:
        tmp_path = Path(tmp)
        fixtures = build_fixtures(tmp_path)
        originals = {name: Path(f["path"]).read_bytes() for name, f in fixtures.items()}
        names = sorted(fixtures)
        pending = list(range(first_case, first_case + n_cases))[::-1]
        pool = [Worker(tmp_path / "queries.npy") for _ in range(max(1, workers))]
        results: list[dict[str, Any]] = []
        start = time.monotonic()
        last_report = start
        try:
            while pending or any(w.task for w in pool):
                for w in pool:
                    if w.task is None and pending:
                        case_id = pending.pop()
                        fixture, kind, data, description = make_case(seed, case_id, names, originals)
                        path = tmp_path / f"case-{case_id}.npz"
                        path.write_bytes(data)
                        w.send({"id": case_id, "path": str(path), "fixture": fixture, "kind": kind,
                                "description": description}, hard_timeout)
                busy = [w for w in pool if w.task]
                wait = max(0.0, min(w.deadline for w in busy) - time.monotonic())
                ready, _, _ = select.select([w.proc.stdout for w in busy], [], [], wait)
                for i, w in enumerate(pool):
                    if w.task is None:
                        continue
                    finished = None
                    if w.proc.stdout in ready:
                        try:
                            finished = w.read_result()
                        except EOFError:
                            code = w.proc.wait()
                            finished = {"outcome": "crash", "error": f"worker died (exit {code})", "seconds": None}
                            pool[i] = Worker(tmp_path / "queries.npy")
                    if finished is None and time.monotonic() > w.deadline:
                        w.kill()
                        finished = {"outcome": "hang", "error": f"no answer within {hard_timeout} s",
                                    "seconds": hard_timeout}
                        pool[i] = Worker(tmp_path / "queries.npy")
                    if finished is not None:
                        task = w.task
                        results.append({**{k: task[k] for k in ("id", "fixture", "kind", "description")},
                                        **{k: v for k, v in finished.items() if k != "id"}})
                        Path(task["path"]).unlink(missing_ok=True)
                        w.task = None
                if progress and time.monotonic() - last_report > 30:
                    last_report = time.monotonic()
                    done = len(results)
                    bad = sum(r["outcome"] in FAILURES for r in results)
                    print(f"  {done}/{n_cases} cases, {bad} failures, {time.monotonic() - start:.0f} s", flush=True)
        finally:
            for w in pool:
                w.close()
        elapsed = time.monotonic() - start
    return summarise(results, seed=seed, elapsed=elapsed, workers=workers, fixtures=names)


FAILURES = ("exception", "out_of_range", "slow", "hang", "crash")


def summarise(results: list[dict[str, Any]], *, seed: int, elapsed: float, workers: int,
              fixtures: list[str]) -> dict[str, Any]:
    """Counts by kind and outcome, the failures (first 100), the slowest case and the peak memory."""
    by_kind: dict[str, Counter] = defaultdict(Counter)
    by_fixture: dict[str, Counter] = defaultdict(Counter)
    for r in results:
        by_kind[r["kind"]][r["outcome"]] += 1
        by_fixture[r["fixture"]][r["outcome"]] += 1
    timed = [r for r in results if r.get("seconds") is not None]
    slowest = max(timed, key=lambda r: r["seconds"]) if timed else None
    failed = [r for r in results if r["outcome"] in FAILURES]
    rarity = Counter(r["outcome"] for r in failed)
    failures = sorted(failed, key=lambda r: (rarity[r["outcome"]], r["id"]))  # the rarest kinds first
    return {
        "seed": seed,
        "cases": len(results),
        "workers": workers,
        "elapsed_s": round(elapsed, 1),
        "slow_limit_s": SLOW_SECONDS,
        "outcomes": dict(Counter(r["outcome"] for r in results)),
        "failures": len(failures),
        "by_kind": {k: dict(v) for k, v in sorted(by_kind.items())},
        "by_fixture": {k: dict(v) for k, v in sorted(by_fixture.items())},
        "fixtures": fixtures,
        "slowest": None if slowest is None else {k: slowest.get(k) for k in
                                                 ("id", "fixture", "kind", "description", "outcome", "seconds")},
        "max_rss_mb": round(max((r.get("max_rss_kb") or 0) for r in results) / 1024, 1) if results else None,
        "failed_cases": [{k: r.get(k) for k in ("id", "fixture", "kind", "description", "outcome", "error",
                                                "seconds", "traceback")} for r in failures[:100]],
        # Loaded, then a query was refused with a project error (e.g. the dimension was edited): passes,
        # listed to show why.
        "query_refused_cases": [{k: r.get(k) for k in ("id", "fixture", "kind", "description", "error")}
                                for r in results if r["outcome"] == "loaded_query_refused"][:30],
    }


def replay(case_id: int, seed: int) -> None:
    """Rerun one case in this process and print what happened (with the traceback)."""
    with tempfile.TemporaryDirectory(prefix="btel-fuzz-") as tmp:
        fixtures = build_fixtures(Path(tmp))
        originals = {name: Path(f["path"]).read_bytes() for name, f in fixtures.items()}
        fixture, kind, data, description = make_case(seed, case_id, sorted(fixtures), originals)
        path = Path(tmp) / "case.npz"
        path.write_bytes(data)
        print(f"case {case_id}: {fixture}, {kind}: {description}")
        result = run_case(str(path), np.load(Path(tmp) / "queries.npy"))
        print(json.dumps({k: v for k, v in result.items() if k != "traceback"}, indent=2))
        print(result.get("traceback", ""))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--cases", type=int, default=50_000)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--case", type=int, default=None, help="replay one case in this process")
    parser.add_argument("--out", default="fuzz_model_files", help="name of the JSON in benchmarks/results/")
    args = parser.parse_args(argv)
    if args.case is not None:
        replay(args.case, args.seed)
        return 0
    sys.path.insert(0, str(HERE))
    from _common import write_results

    print(f"fuzzing btel.load: {args.cases} cases, seed {args.seed}, {args.workers} workers", flush=True)
    load_before = os.getloadavg()
    summary = run_cases(args.cases, args.seed, workers=args.workers, progress=True)
    summary["load_average_before"] = [round(x, 2) for x in load_before]
    summary["load_average_after"] = [round(x, 2) for x in os.getloadavg()]
    summary["command"] = f"python benchmarks/fuzz_model_files.py --cases {args.cases} --seed {args.seed} " \
                         f"--workers {args.workers}"
    path = write_results(args.out, summary)
    print(json.dumps({k: summary[k] for k in ("cases", "elapsed_s", "outcomes", "failures", "slowest", "max_rss_mb")},
                     indent=2))
    for failure in summary["failed_cases"][:20]:
        print(f"  FAIL case {failure['id']} ({failure['fixture']}, {failure['kind']}: {failure['description']}): "
              f"{failure['outcome']} {failure['error']}")
    print(f"written to {path}")
    return 1 if summary["failures"] else 0


if __name__ == "__main__":
    if "--worker" in sys.argv:
        worker_main()
    else:
        sys.exit(main())
