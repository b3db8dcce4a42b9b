"""Fuzz every reader of untrusted input besides model files (issues 20 and 34).

Readers: ground truth as VPR-Bench pickled object arrays (``gt_pickle``), ``.npz`` (``gt_npz``),
CSV (``gt_csv``), MATLAB (``gt_mat``) and UTM positions checked against descriptor counts
(``gt_utm``); hloc HDF5 descriptors (``hdf5``); ``.npy``/``.npz`` descriptor matrices
(``desc_npy``) and memory-mapped ``.npy`` (``desc_mmap``); saved image-descriptor files, loaded and
applied to one small image (``desc_file``); image files (``image``, :func:`read_image`); image
names written into a predictions CSV and a pairs file (``names``). Each reader has seeds —
legitimate files and the crafted hostile files of issues 20 and 34 — and each case is a seed with
seeded mutations (bit flips, truncation, overwritten / deleted / duplicated / inserted bytes, and
for text formats token edits), or a case of one of issue 34's structure-aware families
(``fuzz_families.py``: link graphs and chunk shapes for ``hdf5``, image headers, ring geometries,
names), sometimes mutated further.

A case runs in a worker process (imports done once). It **passes** when the reader returns or
raises a btel error (:class:`~btel.exceptions.BTELError`). It **fails** on any other exception
(a generic error, including a broken invariant such as a pairs file that is not one pair per
line), no answer within ``--timeout`` seconds (a hang: the worker is killed and restarted), the
worker's death (a crash), or peak resident memory above 1 GiB in the worker or a child it waited
for (scipy's MATLAB reader runs in one). ``gt_utm`` runs under ``BTEL_MEMORY_LIMIT=16M``, so that
the radius search's distance bound (16 per pair the limit holds: 1.7·10⁷) is reached in about a
second; under the default limit it is 16 times as many distances (the issue's ring: 15 s).

Run (writes ``benchmarks/results/fuzz_readers.json``)::

    python benchmarks/fuzz_readers.py --cases 20000 --seed 0            # per reader
    python benchmarks/fuzz_readers.py --cases 200 --readers gt_csv,hdf5

``--case READER:ID`` reruns one case in this process with its traceback.
"""

from __future__ import annotations

import argparse
import io
import json
import logging
import os
import pickle
import random
import resource
import select
import struct
import subprocess
import sys
import tempfile
import time
import traceback
import zipfile
from collections import Counter
from pathlib import Path
from typing import Any, Callable

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import fuzz_families as families  # noqa: E402

READERS = ("gt_pickle", "gt_npz", "gt_csv", "gt_mat", "gt_utm", "hdf5", "desc_npy", "desc_mmap", "desc_file",
           "image", "names")
SUFFIX = {"gt_pickle": ".npy", "gt_npz": ".npz", "gt_csv": ".csv", "gt_mat": ".mat", "gt_utm": ".npz",
          "hdf5": ".h5", "desc_npy": ".npz", "desc_mmap": ".npy", "desc_file": ".btel", "image": ".img",
          "names": ".h5"}
#: Readers with a structure-aware family (issue 34): the share of their cases it makes, and its makers.
FAMILIES: dict[str, tuple[float, tuple[Callable[..., Any], ...]]] = {
    "hdf5": (0.5, (families.link_graph, families.chunk_shape)), "image": (0.6, (families.image_header,)),
    "gt_utm": (0.9, (families.ring_geometry,)), "names": (0.9, (families.image_names,))}
MAX_RSS_BYTES = 1 << 30
RESULTS = Path(__file__).resolve().parent / "results" / "fuzz_readers.json"


# ----------------------------------------------------------------------------------------- seeds
def _npy_bytes(array: np.ndarray, protocol: int | None = None) -> bytes:
    buffer = io.BytesIO()
    if protocol is None:
        np.save(buffer, array, allow_pickle=array.dtype == object)
    else:
        np.lib.format.write_array_header_1_0(buffer, {"descr": "|O", "fortran_order": False, "shape": array.shape})
        pickle.dump(array, buffer, protocol=protocol)
    return buffer.getvalue()


def _u(text: str) -> bytes:
    raw = text.encode()
    return b"X" + struct.pack("<I", len(raw)) + raw


def _obj_header(shape: tuple[int, ...]) -> bytes:
    buffer = io.BytesIO()
    np.lib.format.write_array_header_1_0(buffer, {"descr": "|O", "fortran_order": False, "shape": shape})
    return buffer.getvalue()


def _vpr(positives: list[list[int]], dtype: str = "int64") -> np.ndarray:
    array = np.empty((len(positives), 2), dtype=object)
    for q, places in enumerate(positives):
        array[q, 0] = np.int64(q)
        array[q, 1] = np.asarray(places, dtype=dtype)
    return array


def _npz_bytes(**arrays: np.ndarray) -> bytes:
    buffer = io.BytesIO()
    np.savez(buffer, **arrays)
    return buffer.getvalue()


def seeds_gt_pickle() -> list[bytes]:
    out = []
    for protocol in (2, 3, 4, 5):
        out.append(_npy_bytes(_vpr([[0, 1], [], [2, 3, 4]]), protocol))
    out.append(_npy_bytes(_vpr([[5], [1, 2]], ">u2"), 2))
    flat = np.empty(2, dtype=object)
    flat[0], flat[1] = [3, 4], np.array([0, 1], dtype=np.int32)
    out.append(_npy_bytes(flat, 3))
    # Crafted: ndarray over file bytes (an object pointer), an allocation bomb, a nested-list bomb.
    out.append(_obj_header((1,)) + b"\x80\x02cnumpy\nndarray\nK\x01\x85" + _u("O") + b"C\x08"
               + struct.pack("<Q", 0x4141414141) + b"\x87R.")
    out.append(_obj_header((1,)) + b"\x80\x02cnumpy\nndarray\nJ" + struct.pack("<i", 10**8) + b"\x85" + _u("i8")
               + b"\x86R.")
    one = np.empty(1, dtype=object)
    one[0] = [7777777]
    template = pickle.dumps(one, protocol=2)
    sentinel = b"J" + struct.pack("<i", 7777777) + b"a"
    start = template.index(sentinel) - 3
    body = b"]r" + struct.pack("<I", 1000) + b"K\x01a"
    for level in range(1, 23):
        prev = struct.pack("<I", 999 + level)
        body += b"0(j" + prev + b"j" + prev + b"lr" + struct.pack("<I", 1000 + level)
    out.append(_obj_header((1,)) + template[:start] + body + template[start + 3 + len(sentinel):])
    out.append(_obj_header((1, 2)) + b"\x80\x02cos\nsystem\n" + _u("true") + b"\x85R.")
    return out


def seeds_gt_npz() -> list[bytes]:
    utm = np.zeros((20000, 2))
    buffer = io.BytesIO()
    np.savez_compressed(buffer, utmDb=utm, utmQ=utm, posDistThr=np.float64(0.0))
    rng = np.random.default_rng(0)
    out = [
        _npz_bytes(query_places=np.array([2, 0, 1]), n_map=np.int64(3)),
        _npz_bytes(indptr=np.array([0, 2, 2, 3]), indices=np.array([1, 3, 0]), n_map=np.int64(5)),
        _npz_bytes(utmDb=rng.uniform(0, 50, (40, 2)), utmQ=rng.uniform(0, 50, (10, 2)), posDistThr=np.float64(5.0)),
        _npz_bytes(utmDb=np.zeros((3, 2)), utmQ=np.zeros((2, 2)), posDistThr=np.array([1.0, 2.0])),
        buffer.getvalue(),
    ]
    header = io.BytesIO()
    np.lib.format.write_array_header_1_0(header, {"descr": "<f8", "fortran_order": False, "shape": (250_000_000, 2)})
    zbuffer = io.BytesIO()
    with zipfile.ZipFile(zbuffer, "w", zipfile.ZIP_DEFLATED) as zf:
        zf.writestr("utmDb.npy", header.getvalue() + b"\0" * 64)
        zf.writestr("utmQ.npy", _npy_bytes(np.zeros((2, 2))))
        zf.writestr("posDistThr.npy", _npy_bytes(np.float64(1.0)))
    out.append(zbuffer.getvalue())
    return out


def seeds_gt_csv() -> list[bytes]:
    return [b"query,positive\n0,5\n0,6\n2,7\n", b"query,positives\n0,5 6\n1,\n2,7;8\n",
            b"query,positive\n1000000000000,1\n", b"query,positive\n0,1_0\n", "query,positive\n0,\u0661\n".encode(),
            b'query,positives\n0,"' + b"1 " * 70000 + b'"\n']


def seeds_gt_mat() -> list[bytes]:
    import scipy.io

    out = []
    utm_db = np.array([[0.0, 0.0], [10.0, 0.0], [20.0, 0.0]])
    utm_q = np.array([[9.0, 0.0], [21.0, 0.0]])
    for mdict, compress in (({"utmDb": utm_db, "utmQ": utm_q, "posDistThr": 5.0}, False),
                            ({"dbStruct": {"utmDb": utm_db.T, "utmQ": utm_q.T, "posDistThr": 5.0}}, True),
                            ({"indptr": np.array([0, 1, 3]), "indices": np.array([2, 0, 1])}, False),
                            ({"utmDb": np.zeros((20000, 2)), "utmQ": np.zeros((20000, 2)), "posDistThr": 0.0}, True)):
        buffer = io.BytesIO()
        scipy.io.savemat(buffer, mdict, do_compression=compress)
        out.append(buffer.getvalue())
    return out


def seeds_hdf5(folder: Path) -> list[bytes]:
    import h5py

    out = []
    secret = folder / "secret.bin"
    secret.write_bytes(np.arange(64, dtype=np.float32).tobytes())
    rng = np.random.default_rng(0)

    def build(fill: Callable[[Any], None]) -> bytes:
        path = folder / "seed.h5"
        with h5py.File(path, "w") as fh:
            fill(fh)
        return path.read_bytes()

    def hloc(fh: Any, compression: str | None = None) -> None:
        for i in range(4):
            fh.create_group(f"db/{i}.jpg").create_dataset("global_descriptor", data=rng.normal(size=8).astype("f4"),
                                                          compression=compression)

    out.append(build(hloc))
    out.append(build(lambda fh: hloc(fh, "gzip")))
    out.append(build(lambda fh: fh.create_group("a").create_dataset(
        "global_descriptor", shape=(16,), dtype="f4", external=[(str(secret), 0, 64)])))
    out.append(build(lambda fh: fh.create_group("a").create_dataset(
        "global_descriptor", shape=(250_000_000,), dtype="f4", chunks=(1_000_000,), fillvalue=1.0)))
    out.append(build(lambda fh: fh.create_group("a").create_dataset("global_descriptor", shape=(3,), dtype="S8")))

    def loops(fh: Any, names: tuple[str, ...]) -> None:  # issue 34: g["loop"] = g; g["x"] = g; g["y"] = g
        hloc(fh)
        group = fh["db/0.jpg"]
        for name in names:
            group[name] = group

    def lying_chunk(fh: Any) -> None:  # issue 34: 8 floats in a chunk storing 1 GiB of compressed zeros
        ds = fh.create_group("db/a.jpg").create_dataset("global_descriptor", shape=(8,), dtype="f4",
                                                        chunks=(8,), compression="gzip")
        ds.id.write_direct_chunk((0,), families.compressed_zeros(1 << 30), 0)

    out.append(build(lambda fh: loops(fh, ("loop",))))
    out.append(build(lambda fh: loops(fh, ("x", "y"))))
    out.append(build(lying_chunk))
    return out


def seeds_gt_utm() -> list[bytes]:
    rng = np.random.default_rng(0)
    angle = np.linspace(0, 2 * np.pi, 5000, endpoint=False)
    ring = 100 * np.stack([np.cos(angle), np.sin(angle)], 1)
    return [_npz_bytes(utmDb=rng.uniform(0, 50, (40, 2)), utmQ=rng.uniform(0, 50, (10, 2)),
                       posDistThr=np.float64(5.0)),
            _npz_bytes(utmDb=ring, utmQ=np.zeros((50, 2)), posDistThr=np.float64(100 * (1 - 1e-9))),
            _npz_bytes(utmDb=ring, utmQ=np.zeros((400_000, 2)), posDistThr=np.float64(100 * (1 - 1e-9)))]


def seeds_names(folder: Path) -> list[bytes]:
    import h5py

    out = []
    for names in (["db/0001.jpg", "db/0002.jpg", "query/0001.jpg"],
                  ["db/a\nINJECTED db/evil", "db/c d", "db/e"]):
        path = folder / "names.h5"
        with h5py.File(path, "w") as fh:
            for i, name in enumerate(names):
                fh.create_group(name).create_dataset("global_descriptor", data=np.full(8, i, np.float32))
        out.append(path.read_bytes())
    sidecar = {"folder": "/nonexistent", "images": [["0.png", 1, 1], ["1 2.png", 1, 1]]}
    out.append(json.dumps(sidecar).encode())
    return out


def seeds_desc_npy() -> list[bytes]:
    X = np.random.default_rng(0).normal(size=(6, 8)).astype(np.float32)
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w", zipfile.ZIP_DEFLATED) as zf:
        with zf.open("X.npy", "w", force_zip64=True) as member:
            np.lib.format.write_array_header_1_0(member, {"descr": "<f4", "fortran_order": False,
                                                          "shape": (10_000_000, 8)})
            member.write(b"\0" * (1 << 20))
    return [_npz_bytes(X=X), buffer.getvalue(), _npz_bytes(a=X, b=X[:2])]


def seeds_desc_file(folder: Path) -> list[bytes]:
    from btel.descriptors import get_descriptor

    rng = np.random.default_rng(0)
    images = [rng.integers(0, 255, size=(96, 128), dtype=np.uint8) for _ in range(6)]
    out = []
    for descriptor in (get_descriptor("hog"), get_descriptor("patchnorm"),
                       get_descriptor("densevlad", n_clusters=4, n_components=3, max_descriptors=2000,
                                      random_state=0).fit(images)):
        out.append(descriptor.save(folder / "d.btel").read_bytes())
    return out


# ------------------------------------------------------------------------------------- mutations
_TOKENS = [b"1000000000000", b"-1", b"1e400", b"nan", b"9" * 40, b"1_0", "\u0661".encode(), b'"', b"\0",
           b"\xff\xfe", b";;", b",,,,", b"\n" * 3, b"x" * 5000, b"2147483648", b"18446744073709551616"]


def mutate(data: bytes, rng: random.Random, text: bool) -> tuple[bytes, str]:
    """One seeded mutation of ``data``; returns (mutated bytes, description)."""
    buf = bytearray(data)
    kinds = ["bitflip", "truncate", "overwrite", "delete", "duplicate", "insert", "int"]
    if text:
        kinds += ["token", "token"]
    kind = rng.choice(kinds)
    n = len(buf)
    if n == 0:
        return bytes(rng.randbytes(rng.randint(1, 64))), "random"
    if kind == "bitflip":
        for _ in range(rng.randint(1, 8)):
            i = rng.randrange(n)
            buf[i] ^= 1 << rng.randrange(8)
    elif kind == "truncate":
        del buf[rng.randrange(n):]
    elif kind == "overwrite":
        i = rng.randrange(n)
        k = rng.randint(1, 16)
        buf[i:i + k] = rng.randbytes(k)
    elif kind == "delete":
        i = rng.randrange(n)
        del buf[i:i + rng.randint(1, 64)]
    elif kind == "duplicate":
        i = rng.randrange(n)
        span = buf[i:i + rng.randint(1, 256)]
        j = rng.randrange(n)
        buf[j:j] = span * rng.randint(1, 8)
    elif kind == "insert":
        j = rng.randrange(n + 1)
        buf[j:j] = rng.randbytes(rng.randint(1, 32))
    elif kind == "int":  # a 1/2/4/8-byte little-endian integer set to an extreme value
        width = rng.choice([1, 2, 4, 8])
        i = rng.randrange(max(1, n - width))
        value = rng.choice([0, 1, 2**(8 * width - 1) - 1, 2**(8 * width) - 1, 2**(8 * width - 2), 255])
        buf[i:i + width] = (value % 2**(8 * width)).to_bytes(width, "little")
    else:  # token: replace a run of digits (or any byte) by an odd token
        digits = [i for i, b in enumerate(buf) if 48 <= b <= 57]
        i = rng.choice(digits) if digits else rng.randrange(n)
        j = i
        while j < n and 48 <= buf[j] <= 57:
            j += 1
        buf[i:max(j, i + 1)] = rng.choice(_TOKENS)
    return bytes(buf), kind


def make_case(reader: str, seed: int, case_id: int, seeds: list[bytes]) -> tuple[bytes, str, dict[str, Any]]:
    """Case ``case_id`` of ``reader``: (file bytes, description, keyword arguments of the reader)."""
    rng = random.Random(f"{seed}:{reader}:{case_id}")
    args: dict[str, Any] = {"grey": rng.random() < 0.5} if reader == "image" else {}
    if case_id < len(seeds):  # every seed is a case as it is
        return seeds[case_id], f"seed {case_id}", args
    share, makers = FAMILIES.get(reader, (0.0, ()))
    if rng.random() < share:
        maker = rng.choice(makers)
        made = maker(rng.choice(seeds), rng) if maker is families.image_header else maker(rng)
        data, kind = made[0], made[1]
        args.update(made[2] if len(made) > 2 else {})
        if rng.random() < 0.25:
            data, k = mutate(data, rng, text=False)
            kind += "+" + k
        return data, kind, args
    base = rng.randrange(len(seeds))
    data, kind = seeds[base], ""
    for _ in range(rng.choice([1, 1, 1, 2, 3])):
        data, k = mutate(data, rng, text=reader == "gt_csv")
        kind += ("+" if kind else "") + k
    return data, f"seed {base} {kind}", args


# ---------------------------------------------------------------------------------------- worker
def run_reader(reader: str, path: str, args: dict[str, Any] | None = None) -> str:
    """Run one reader on ``path`` with ``args``; return a short outcome (raises what the reader raises)."""
    args = args or {}
    if reader.startswith("gt_"):
        from btel.datasets import GroundTruth

        if reader == "gt_utm":
            os.environ["BTEL_MEMORY_LIMIT"] = "16M"
        try:
            gt = GroundTruth.from_file(path, **args)
        finally:
            os.environ.pop("BTEL_MEMORY_LIMIT", None)
        return f"ok {gt.kind} {gt.n_queries}"
    if reader in ("hdf5", "desc_npy", "desc_mmap"):
        from btel.descriptors.npy import load_descriptor_matrix

        X = load_descriptor_matrix(path, mmap_mode="r" if reader == "desc_mmap" else None)
        if X.dtype != np.float32 or not X.flags.c_contiguous or not np.isfinite(X).all():
            raise AssertionError(f"descriptors of dtype {X.dtype}, C-contiguous {X.flags.c_contiguous}")
        return f"ok {X.shape}"
    if reader == "image":
        from btel.descriptors.images import read_image

        image = read_image(path, grey=args.get("grey", False))
        if image.dtype != np.uint8 or image.ndim != (2 if args.get("grey") else 3):
            raise AssertionError(f"image of dtype {image.dtype}, shape {image.shape}")
        return f"ok {image.shape}"
    if reader == "names":
        return families.read_names(path)
    if reader == "desc_file":
        from btel.descriptors.base import load_descriptor

        descriptor = load_descriptor(path)
        image = (np.arange(64 * 48, dtype=np.uint8).reshape(48, 64) * 7) % 251
        X = descriptor.transform([image])
        if not np.isfinite(X).all():
            raise AssertionError("non-finite descriptors")
        return f"ok {X.shape}"
    raise ValueError(reader)


def worker_main() -> None:
    import warnings

    import btel  # noqa: F401 - imports once
    from btel.exceptions import BTELError

    from _common import peak_rss  # the worker runs as a script: this folder is on its path

    warnings.simplefilter("ignore")
    logging.disable(logging.WARNING)  # "n of n queries have no positive" on every ring case
    resource.setrlimit(resource.RLIMIT_AS, (4 << 30, 4 << 30))
    for line in sys.stdin:
        reader, path, args = line.rstrip("\n").split("\t", 2)
        start = time.perf_counter()
        try:
            outcome, error = run_reader(reader, path, json.loads(args)), ""
        except BTELError as exc:
            outcome, error = "refused", f"{type(exc).__name__}: {str(exc)[:160]}"
        except BaseException as exc:  # noqa: BLE001 - the harness records it as a failure
            outcome, error = "generic", f"{type(exc).__name__}: {str(exc)[:300]}"
        rss = max(peak_rss(), 1024 * resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss)
        sys.stdout.write(json.dumps({"outcome": outcome, "error": error, "rss": rss,
                                     "seconds": time.perf_counter() - start}) + "\n")
        sys.stdout.flush()


class Worker:
    def __init__(self) -> None:
        env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[1] / "src")}
        self.proc = subprocess.Popen([sys.executable, __file__, "--worker"], stdin=subprocess.PIPE,
                                     stdout=subprocess.PIPE, text=True, env=env, bufsize=1)

    def run(self, reader: str, path: str, args: dict[str, Any], timeout: float) -> dict[str, Any]:
        self.proc.stdin.write(f"{reader}\t{path}\t{json.dumps(args)}\n")
        self.proc.stdin.flush()
        ready, _, _ = select.select([self.proc.stdout], [], [], timeout)
        if not ready:
            self.kill()
            return {"outcome": "hang", "error": f"no answer in {timeout} s"}
        line = self.proc.stdout.readline()
        if not line:
            code = self.proc.wait()
            self.proc = None
            return {"outcome": "crash", "error": f"worker died (exit {code})"}
        return json.loads(line)

    def kill(self) -> None:
        if self.proc is not None:
            self.proc.kill()
            self.proc.wait()
            self.proc = None

    @property
    def alive(self) -> bool:
        return self.proc is not None


def build_seeds(reader: str, folder: Path) -> list[bytes]:
    makers = {"gt_pickle": seeds_gt_pickle, "gt_npz": seeds_gt_npz, "gt_csv": seeds_gt_csv, "gt_mat": seeds_gt_mat,
              "gt_utm": seeds_gt_utm, "hdf5": lambda: seeds_hdf5(folder), "desc_npy": seeds_desc_npy,
              "desc_mmap": families.mmap_seeds, "desc_file": lambda: seeds_desc_file(folder),
              "image": families.image_seeds, "names": lambda: seeds_names(folder)}
    return makers[reader]()


def run_cases(n_cases: int, *, seed: int = 0, readers: tuple[str, ...] = READERS, timeout: float = 10.0,
              progress: bool = False, deadline: float | None = None) -> dict[str, Any]:
    """Run ``n_cases`` cases per reader; return the summary (see the module docstring)."""
    summary: dict[str, Any] = {"seed": seed, "cases_per_reader": n_cases, "readers": {}}
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        worker = Worker()
        try:
            for reader in readers:
                seeds = build_seeds(reader, folder)
                counts: Counter[str] = Counter()
                failures: list[dict[str, Any]] = []
                peak = 0
                done = 0
                path = folder / f"case{SUFFIX[reader]}"
                began = time.time()
                for case_id in range(n_cases):
                    if deadline is not None and time.time() > deadline:
                        break
                    data, description, args = make_case(reader, seed, case_id, seeds)
                    path.write_bytes(data)
                    if not worker.alive:
                        worker = Worker()
                    result = worker.run(reader, str(path), args, timeout)
                    outcome = result["outcome"]
                    if outcome.startswith("ok"):
                        outcome = "ok"
                    rss = int(result.get("rss", 0))
                    peak = max(peak, rss)
                    if rss > MAX_RSS_BYTES and outcome in ("ok", "refused"):
                        outcome = "memory"
                    if rss > MAX_RSS_BYTES:
                        worker.kill()  # start the next case from a fresh peak
                    counts[outcome] += 1
                    done += 1
                    if outcome not in ("ok", "refused"):
                        failures.append({"id": case_id, "case": description, "outcome": outcome,
                                         "error": result.get("error", ""), "bytes": len(data), "args": args})
                    if progress and done % 500 == 0:
                        print(f"{reader}: {done} cases {dict(counts)}", flush=True)
                summary["readers"][reader] = {
                    "cases": done, "seeds": len(seeds), "outcomes": dict(counts),
                    "failures": len(failures), "failed_cases": failures[:50],
                    "peak_worker_rss_mib": round(peak / 2**20, 1), "seconds": round(time.time() - began, 1)}
                if progress:
                    print(f"{reader}: done, {done} cases, {dict(counts)}", flush=True)
        finally:
            worker.kill()
    summary["failures"] = sum(r["failures"] for r in summary["readers"].values())
    return summary


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--cases", type=int, default=2000, help="cases per reader")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--readers", default=",".join(READERS))
    parser.add_argument("--timeout", type=float, default=10.0)
    parser.add_argument("--minutes", type=float, default=None, help="stop each run after this long")
    parser.add_argument("--out", default=str(RESULTS))
    parser.add_argument("--case", default=None, help="READER:ID — rerun one case here with its traceback")
    parser.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.worker:
        worker_main()
        return
    if args.case:
        reader, case_id = args.case.split(":")
        with tempfile.TemporaryDirectory() as tmp:
            seeds = build_seeds(reader, Path(tmp))
            data, description, reader_args = make_case(reader, args.seed, int(case_id), seeds)
            path = Path(tmp) / f"case{SUFFIX[reader]}"
            path.write_bytes(data)
            print(description, len(data), "bytes", reader_args)
            try:
                print(run_reader(reader, str(path), reader_args))
            except Exception:
                traceback.print_exc()
        return
    readers = tuple(r for r in args.readers.split(",") if r)
    deadline = None if args.minutes is None else time.time() + 60 * args.minutes
    start = time.time()
    summary = run_cases(args.cases, seed=args.seed, readers=readers, timeout=args.timeout, progress=True,
                        deadline=deadline)
    summary["seconds"] = round(time.time() - start, 1)
    summary["command"] = " ".join([Path(sys.executable).name, *sys.argv])
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(summary, indent=2) + "\n")
    for reader, r in summary["readers"].items():
        print(f"{reader:10s} {r['cases']:6d} cases  {r['outcomes']}  failures {r['failures']}  "
              f"peak RSS {r['peak_worker_rss_mib']} MiB  {r['seconds']} s")
    print(f"total failures: {summary['failures']} ({summary['seconds']} s); written to {args.out}")


if __name__ == "__main__":
    main()
