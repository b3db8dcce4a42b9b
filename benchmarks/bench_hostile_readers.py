"""Issue 34's hostile files for the readers (and rounds 3 and 4), each run as a user would, with its time and peak memory.

Every case crafts the issue's file (or the finding made while fixing it) and runs one command in
a fresh process: ``btel train``, ``btel extract``, ``btel evaluate`` or the Python call named. It
records the exit status, the wall time, the peak resident memory of the process and its children
(``os.wait4``), whether stderr held a traceback or a bare ``MemoryError``, and the last line of
stderr. The target (issue 34, "Done when"): ≤ 60 s, < 1 GiB, one line, no traceback.

    python benchmarks/bench_hostile_readers.py                        # this checkout
    python benchmarks/bench_hostile_readers.py --src ../main/src --name bench_hostile_readers_before

Writes ``benchmarks/results/bench_hostile_readers.json``. Cases that never end are killed at
``--timeout`` seconds (default 90) and reported as such. Rounds 3 and 4 (``--only "round 3"``, ``"round 4"``) run
with their address space capped at 6 GiB, so that a case that would take the machine's memory fails alone.
"""

from __future__ import annotations

import argparse
import json
import os
import struct
import subprocess
import sys
import tempfile
import zlib
from pathlib import Path
from typing import Any

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

from _common import write_results  # noqa: E402
from fuzz_families import compressed_zeros, jpeg_of_empty_scans  # noqa: E402

BTEL = [sys.executable, "-m", "btel.cli"]
#: A Python call of the library run as a user would: a btel error is its one line, anything else a traceback.
API = ("import sys\nfrom btel.exceptions import BTELError\ntry:\n    {call}\nexcept BTELError as exc:\n"
       "    sys.exit(f'Error: {{type(exc).__name__}}: {{exc}}')")
#: A small process started before anything is crafted, which runs each case and reports it: a child
#: forked from this script, grown by the crafting, would carry its memory in ru_maxrss past exec.
#: os.wait4 gives the case's peak resident memory, its children's included.
SPAWNER = r"""
import json, os, resource, signal, subprocess, sys, threading, time
for line in sys.stdin:
    job = json.loads(line)
    start = time.perf_counter()
    cap = job.get("max_bytes")
    limit = (lambda: resource.setrlimit(resource.RLIMIT_AS, (cap, cap))) if cap else None
    proc = subprocess.Popen(job["command"], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, env=job["env"],
                            start_new_session=True, preexec_fn=limit)
    err = []
    reader = threading.Thread(target=lambda: err.append(proc.stderr.read()), daemon=True)
    reader.start()
    timer = threading.Timer(job["timeout"], lambda: os.killpg(proc.pid, signal.SIGKILL))
    timer.start()
    _, status, usage = os.wait4(proc.pid, 0)
    seconds = time.perf_counter() - start
    timer.cancel()
    reader.join(5)
    print(json.dumps({"status": status, "seconds": seconds, "maxrss_kib": usage.ru_maxrss,
                      "stderr": b"".join(err).decode(errors="replace")}), flush=True)
"""


def api(call: str) -> list[str]:
    return [sys.executable, "-c", API.format(call=call)]


def _png(width: int, height: int, colour_type: int, idat: bytes, idat_length: int | None = None) -> bytes:
    def chunk(kind: bytes, data: bytes, length: int | None = None) -> bytes:
        size = len(data) if length is None else length
        return struct.pack(">I", size) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    header = struct.pack(">IIBBBBB", width, height, 8, colour_type, 0, 0, 0)
    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", header) + chunk(b"IDAT", idat, idat_length)
            + chunk(b"IEND", b""))


def _zero_rows(width: int, height: int, channels: int) -> bytes:
    """The zlib stream of an all-black image's rows (filter byte 0 + zeros): all zero bytes."""
    return compressed_zeros(height * (1 + width * channels))


def _descriptor(fh: Any, name: str, rng: np.random.Generator) -> Any:
    return fh.create_group(name).create_dataset("global_descriptor", data=rng.normal(size=8).astype("f4"))


def craft(folder: Path) -> list[dict[str, Any]]:
    """Write the files and return the cases: name, command, file size."""
    import h5py
    import scipy.io

    cases: list[dict[str, Any]] = []
    rng = np.random.default_rng(0)

    def add(case: str, file: Path, command: list[str], pairs: Path | None = None) -> None:
        cases.append({"case": case, "file": file, "command": command, "pairs": pairs})

    def hloc(path: Path, extra: Any) -> Path:
        with h5py.File(path, "w") as fh:
            for i in range(4):
                _descriptor(fh, f"db/{i}.jpg", rng)
            extra(fh)
        return path

    def self_links(*names: str) -> Any:
        def link(fh: Any) -> None:
            for name in names:
                fh["db/0.jpg"][name] = fh["db/0.jpg"]
        return link

    def chunk_of(values: int) -> Any:  # 8 values in one gzip chunk of ``values``, storing 1 GiB of zeros
        def write(fh: Any) -> None:
            group = fh.create_group("db/x.jpg")
            ds = group.create_dataset("global_descriptor", shape=(8,), dtype="f4", maxshape=(None,),
                                      chunks=(values,), compression="gzip")
            ds.id.write_direct_chunk((0,), compressed_zeros(2**30), 0)
        return write

    for name, extra in (("loop", self_links("loop")), ("two_self_links", self_links("x", "y")),
                        ("chunk_2e28", chunk_of(2**28)), ("chunk_8_stores_1GiB", chunk_of(8))):
        path = hloc(folder / f"{name}.h5", extra)
        add(f"hdf5 {name}: btel train", path, [*BTEL, "train", str(path), "-o", str(folder / f"{name}.btel")])
        if name == "loop":
            add("hdf5 loop: load_descriptor_matrix", path,
                api(f"from btel.descriptors.npy import load_descriptor_matrix as f; f({str(path)!r})"))

    for name, data in (("idat_0x7fffffff", _png(8, 8, 0, zlib.compress(b"\0" * 72), 0x7FFFFFFF)),
                       ("grey_30000x30000", _png(30000, 30000, 0, _zero_rows(30000, 30000, 1))),
                       ("colour_20000x20000", _png(20000, 20000, 2, _zero_rows(20000, 20000, 3)))):
        images = folder / name
        images.mkdir()
        (images / "a.png").write_bytes(data)
        add(f"png {name}: btel extract", images / "a.png",
            [*BTEL, "extract", str(images), "-o", str(folder / f"{name}.npy"), "--no-progress"])
    colour = folder / "colour_20000x20000" / "a.png"
    add("png colour_20000x20000: read_image (colour, the gallery's read)", colour,
        api(f"from btel.descriptors.images import read_image; read_image({str(colour)!r})"))

    np.save(folder / "db.npy", rng.normal(size=(50_000, 8)).astype("f4"))
    np.save(folder / "q.npy", rng.normal(size=(50, 8)).astype("f4"))
    angle = np.linspace(0, 2 * np.pi, 50_000, endpoint=False)
    ring = folder / "ring.npz"
    np.savez_compressed(ring, utmDb=100 * np.stack([np.cos(angle), np.sin(angle)], 1),
                        utmQ=np.zeros((4_000_000, 2)), posDistThr=np.float64(100 * (1 - 1e-9)))
    add("utm ring 50k × 4M: btel evaluate (50 queries)", ring,
        [*BTEL, "evaluate", "--db", str(folder / "db.npy"), "--queries", str(folder / "q.npy"),
         "--ground-truth", str(ring), "--methods", "bruteforce", "--no-reference", "--no-progress",
         "--out", str(folder / "run")])
    add("utm ring 50k × 4M: GroundTruth.from_file (no counts)", ring,
        api(f"from btel.datasets import GroundTruth; GroundTruth.from_file({str(ring)!r})"))

    for name, rows in (("mat_256MiB", 16 * 2**20), ("mat_244MiB", 16_000_000)):
        path = folder / f"{name}.mat"
        scipy.io.savemat(path, {"utmDb": np.zeros((rows, 2)), "utmQ": np.zeros((2, 2)), "posDistThr": 1.0},
                         do_compression=True)
        add(f".mat inflating to {rows * 16 / 2**20:.0f} MiB: GroundTruth.from_file", path,
            api(f"from btel.datasets import GroundTruth; GroundTruth.from_file({str(path)!r})"))

    for name, descr, fortran in (("fortran_f32", "<f4", True), ("c_f64", "<f8", False)):
        path = folder / f"{name}.npy"
        n = 1_200_000_000 // np.dtype(descr).itemsize // 100
        with open(path, "wb") as fh:
            header = {"descr": descr, "fortran_order": fortran, "shape": (n, 100)}
            np.lib.format.write_array_header_1_0(fh, header)
            fh.truncate(fh.tell() + n * 100 * np.dtype(descr).itemsize)
        add(f"sparse 1.2 GB {name}.npy: load_descriptor_matrix(mmap_mode='r')", path,
            api("from btel.descriptors.npy import load_descriptor_matrix as f; "
                f"f({str(path)!r}, mmap_mode='r')"))
    add("sparse 1.2 GB fortran_f32.npy: btel train", folder / "fortran_f32.npy",
        [*BTEL, "train", str(folder / "fortran_f32.npy"), "-o", str(folder / "f.btel")])

    for name, bad in (("newline", "db/a\nINJECTED db/evil"), ("space", "db/c d")):
        path = folder / f"names_{name}.h5"
        with h5py.File(path, "w") as fh:
            for image in (bad, "db/e", "db/f", "query/q1", "query/q2"):
                _descriptor(fh, image, rng)
        pairs = folder / f"pairs_{name}.txt"
        add(f"names ({name}): btel evaluate --pairs", path,
            [*BTEL, "evaluate", "--db", f"{path}:db/", "--queries", f"{path}:query/", "--methods",
             "bruteforce", "--no-reference", "--pairs", str(pairs), "--k", "3", "--no-progress", "--out",
             str(folder / f"run_{name}")], pairs)
    cases += craft_round3(folder, rng)
    cases += craft_round4(folder, rng)
    for case in cases:
        case["file_bytes"] = os.stat(case.pop("file")).st_blocks * 512  # on disk (the sparse files are holes)
    return cases


def _adder(out: list[dict[str, Any]], round_name: str) -> Any:
    """``add(case, file, command)``: a case of ``round_name``, run with its address space capped at 6 GiB."""
    def add(case: str, file: Path, command: list[str]) -> None:
        out.append({"case": f"{round_name}: {case}", "file": file, "command": command, "pairs": None,
                    "max_bytes": 6 * 2**30})

    return add


def craft_round3(folder: Path, rng: np.random.Generator) -> list[dict[str, Any]]:
    """The hostile inputs of round 3 (issue 35/37's session of 2026-11-28): sizes a file claims, regexes
    that backtrack, decoders that loop, run folders edited by hand."""
    import cv2
    import h5py

    from btel.core.modelfile import load_arrays, save_arrays
    from btel.descriptors.hog import HOGDescriptor

    out: list[dict[str, Any]] = []
    add = _adder(out, "round 3")

    root = folder / "round3"
    root.mkdir()
    db, q, model = root / "db.npy", root / "q.npy", root / "m.btel.npz"
    np.save(db, rng.normal(size=(200, 64)).astype("f4"))
    np.save(q, rng.normal(size=(200, 64)).astype("f4"))
    subprocess.run([*BTEL, "train", str(db), "-o", str(model), "--method", "btel-c", "--budget", "5KB"],
                   check=True, capture_output=True)
    add("--hmm-speed 10⁹ on a 200-place model: btel localize --hmm", model,
        [*BTEL, "localize", str(model), str(q), "-o", str(root / "p1.csv"), "--hmm", "--hmm-speed", "1000000000"])
    arrays, header = load_arrays(model)
    header = {k: v for k, v in header.items() if k not in ("format", "format_version", "saved_by")}
    header["state"]["n_places"] = 8_000_000
    big = root / "bigN.btel.npz"
    save_arrays(big, {"weights": rng.normal(size=(23, 64)).astype("f4"),
                      "bias": rng.normal(size=23).astype("f4")}, header)
    np.save(root / "q10.npy", np.load(q)[:10])
    add("a 1 KB model claiming 8·10⁶ places: btel localize --hmm (10 queries)", big,
        [*BTEL, "localize", str(big), str(root / "q10.npy"), "-o", str(root / "p2.csv"), "--hmm"])
    images = root / "im30"
    images.mkdir()
    for i in range(30):
        cv2.imwrite(str(images / f"{i:02d}.png"), rng.integers(0, 255, (32, 64), dtype=np.uint8))
    HOGDescriptor(orientations=48_000).save(root / "hog_big.btel.npz")
    add("a 600 B HOG asking 48,000 orientations: btel extract (30 images)", root / "hog_big.btel.npz",
        [*BTEL, "extract", str(images), "-o", str(root / "im30.npy"), "--descriptor", str(root / "hog_big.btel.npz"),
         "--no-progress"])
    groups = root / "groups.h5"
    with h5py.File(groups, "w", libver="latest") as fh:
        for i in range(200_000):
            fh.create_group(f"g{i}")
        for i in range(5):
            _descriptor(fh, f"img{i}.jpg", rng)
    add("an .h5 of 200,000 empty groups: btel train", groups,
        [*BTEL, "train", str(groups), "-o", str(root / "g.btel.npz"), "--method", "btel-c", "--budget", "5KB"])
    digits = root / "digits.txt"
    digits.write_text("1" * 30_000 + "x\n")
    add("a line of 30,000 digits and an x: btel localize --stream", digits,
        [*BTEL, "localize", str(model), "--stream", "--input", str(digits)])
    cell = root / "cell.npy"
    cell.write_text("1" * 30_000 + "x\n")
    add("a text 'npy' of one 30,000-digit cell: btel train", cell,
        [*BTEL, "train", str(cell), "-o", str(root / "c.btel.npz"), "--method", "btel-c", "--budget", "5KB"])
    runs, docs = root / "runs", root / "docs"
    (runs / "accuracy").mkdir(parents=True)
    (runs / "accuracy" / "results.json").write_text('{"rows": [], "run": {}}')
    docs.mkdir()
    (docs / "results.md").write_text("<!-- a:start -->" * 20_000)
    add("a results.md of 20,000 unclosed markers: btel report", docs / "results.md",
        [*BTEL, "report", "--runs", str(runs), "--docs", str(docs), "--overwrite"])
    jpegs = root / "jpg"
    jpegs.mkdir()
    (jpegs / "a.jpg").write_bytes(jpeg_of_empty_scans(2_000, size=8000))
    add("a progressive 8000×8000 JPEG of 2,000 empty scans: btel extract", jpegs / "a.jpg",
        [*BTEL, "extract", str(jpegs), "-o", str(root / "j.npy"), "--no-progress"])
    run = root / "run"
    subprocess.run([*BTEL, "evaluate", "--db", str(db), "--queries", str(q), "--methods", "btel-c", "--budget", "5KB",
                    "--no-reference", "--no-progress", "--out", str(run)], check=True, capture_output=True)
    metrics = json.loads((run / "metrics.json").read_text())
    metrics["run"]["complete"] = False
    metrics["run"]["extra"]["options"]["--budget"] = 5
    (run / "metrics.json").write_text(json.dumps(metrics))
    add("metrics.json edited ('--budget': 5): btel evaluate --resume", run / "metrics.json",
        [*BTEL, "evaluate", "--resume", str(run)])
    nested = root / "nested"
    nested.mkdir()
    (nested / "metrics.json").write_text("[" * 100_000 + "]" * 100_000)
    add("metrics.json nested 100,000 deep: btel evaluate --resume", nested / "metrics.json",
        [*BTEL, "evaluate", "--resume", str(nested)])
    return out



def run(spawner: subprocess.Popen, command: list[str], timeout: float, env: dict[str, str],
        max_bytes: int | None = None) -> dict[str, Any]:
    """Run ``command`` through ``spawner``: its exit status, wall time, peak RSS (children's too), stderr."""
    spawner.stdin.write(json.dumps({"command": command, "timeout": timeout, "env": env, "max_bytes": max_bytes})
                        + "\n")
    spawner.stdin.flush()
    done = json.loads(spawner.stdout.readline())
    status, seconds, text = done["status"], done["seconds"], done["stderr"]
    killed = os.WIFSIGNALED(status)
    lines = [line for line in text.splitlines() if line.strip()]
    return {"exit": None if killed else os.WEXITSTATUS(status), "killed": killed,
            "timed_out": killed and seconds >= timeout - 1, "seconds": round(seconds, 1),
            "peak_rss_mib": round(done["maxrss_kib"] / 1024, 1), "stderr_lines": len(lines),
            "traceback": "Traceback" in text, "bare_memory_error": "MemoryError" in text,
            "last_line": lines[-1][:300] if lines else ""}


def _tiff_of_one_tile(size: int, tile: int) -> bytes:
    """An RGBA TIFF of ``size``² pixels in ``tile``² tiles, its one tile a deflate stream of zeros."""
    data = compressed_zeros(tile * tile * 4)
    entries = [(256, 3, size), (257, 3, size), (259, 3, 8), (262, 3, 2), (277, 3, 4), (284, 3, 1),
               (322, 4, tile), (323, 4, tile), (324, 4, 0), (325, 4, len(data)), (338, 3, 2)]
    offset = 8 + 2 + 12 * (len(entries) + 1) + 4 + 8  # the header, the IFD with BitsPerSample, its 4 values
    ifd = [struct.pack("<HHII", 258, 3, 4, offset - 8)]
    for tag, kind, value in entries:
        value = offset if tag == 324 else value
        ifd.append(struct.pack("<HHII", tag, kind, 1, value) if kind == 4 else struct.pack("<HHIHH", tag, kind, 1, value, 0))
    ifd.sort(key=lambda entry: struct.unpack("<H", entry[:2])[0])
    body = struct.pack("<H", len(ifd)) + b"".join(ifd) + struct.pack("<I", 0) + struct.pack("<4H", 8, 8, 8, 8)
    return b"II*\x00" + struct.pack("<I", 8) + body + data


def craft_round4(folder: Path, rng: np.random.Generator) -> list[dict[str, Any]]:
    """The hostile inputs of round 4 (issue 35/37's session of 2026-11-28, the second): sizes a file claims
    before any reader saw it, zip directories, TIFF tiles, kernel files, options that never end."""
    import zipfile

    import cv2

    out: list[dict[str, Any]] = []
    add = _adder(out, "round 4")

    root = folder / "round4"
    root.mkdir()
    db, q = root / "db.npy", root / "q.npy"
    np.save(db, rng.normal(size=(200, 64)).astype("f4"))
    np.save(q, rng.normal(size=(50, 64)).astype("f4"))
    sparse = root / "sparse_gt.npy"
    with open(sparse, "wb") as fh:
        np.lib.format.write_array_header_1_0(fh, {"descr": "<i8", "fortran_order": False, "shape": (2_500_000_000,)})
        fh.truncate(fh.tell() + 20_000_000_000)
    add("a ground truth claiming 2.5·10⁹ places (4 KB on disk, 20 GB by size): btel evaluate", sparse,
        [*BTEL, "evaluate", "--db", str(db), "--queries", str(q), "--ground-truth", str(sparse), "--methods", "lsh",
         "--budget", "2KB", "--out", str(root / "run_sparse")])
    many = root / "many.npz"
    with zipfile.ZipFile(many, "w") as archive:
        for i in range(300_000):
            archive.writestr(f"{i:07d}.npy", b"")
    add("an .npz listing 300,000 members: btel info", many, [*BTEL, "info", str(many)])
    tiles = root / "tiles"
    tiles.mkdir()
    (tiles / "a.tif").write_bytes(_tiff_of_one_tile(16, 16_000))
    add("a 16×16 TIFF in 16000×16000 tiles: btel extract", tiles / "a.tif",
        [*BTEL, "extract", str(tiles), "-o", str(root / "t.npy"), "--no-progress"])
    if Path("/proc/self/mem").exists():
        kernel = root / "kernel"
        kernel.mkdir()
        cv2.imwrite(str(kernel / "0.png"), np.zeros((32, 64), np.uint8))
        (kernel / "1.png").symlink_to("/proc/self/mem")
        add("an image that is a link to /proc/self/mem (EIO on read): btel extract", kernel / "0.png",
            [*BTEL, "extract", str(kernel), "-o", str(root / "k.npy"), "--no-progress"])
    model, lines = root / "m.btel.npz", root / "q.txt"
    subprocess.run([*BTEL, "train", str(db), "-o", str(model), "--method", "lsh", "--budget", "2KB"], check=True,
                   capture_output=True)
    np.savetxt(lines, np.load(q)[:5])
    add("--follow --idle-timeout nan: btel localize --stream", lines,
        [*BTEL, "localize", str(model), "--stream", "--input", str(lines), "--follow", "--idle-timeout", "nan"])
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--src", default=str(HERE.parent / "src"), help="the btel source tree to run")
    parser.add_argument("--timeout", type=float, default=90.0)
    parser.add_argument("--name", default="bench_hostile_readers",
                        help="results file benchmarks/results/NAME.json")
    parser.add_argument("--only", default=None, metavar="TEXT",
                        help="run the cases whose name holds TEXT, replacing them in an existing NAME.json")
    args = parser.parse_args()
    env = {**os.environ, "PYTHONPATH": args.src}
    env.pop("BTEL_MEMORY_LIMIT", None)
    spawner = subprocess.Popen([sys.executable, "-c", SPAWNER], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                               text=True)
    rows = []
    with tempfile.TemporaryDirectory(prefix="btel-hostile-") as tmp:
        for case in craft(Path(tmp)):
            if args.only and args.only not in case["case"]:
                continue
            result = {"case": case["case"], "file_bytes": case["file_bytes"],
                      **run(spawner, case["command"], args.timeout, env, case.get("max_bytes"))}
            ok = (not result["killed"] and result["seconds"] <= 60 and result["peak_rss_mib"] < 1024
                  and not result["traceback"] and not result["bare_memory_error"])
            if case["pairs"] is not None:  # exactly one pair (two fields) per line: 2 queries × top 3
                lines = case["pairs"].read_text().split("\n")[:-1] if case["pairs"].is_file() else []
                result["pairs_lines"] = len(lines)
                result["pairs_one_per_line"] = not lines or (len(lines) == 6 and all(
                    len(line.split()) == 2 for line in lines))
                ok = ok and result["pairs_one_per_line"]
            result["meets_target"] = ok
            rows.append(result)
            print(f"{'ok ' if ok else 'MISS'} {result['case'][:62]:62s} exit {result['exit']} "
                  f"{result['seconds']:6.1f} s {result['peak_rss_mib']:7.1f} MiB  "
                  f"{result['last_line'][:100]}", flush=True)
    spawner.stdin.close()
    spawner.wait()
    command = " ".join([Path(sys.executable).name, *sys.argv])
    path = HERE / "results" / f"{args.name}.json"
    if args.only and path.is_file():  # keep the other cases of the earlier run
        earlier = json.loads(path.read_text())
        done = {r["case"] for r in rows}
        rows = [r for r in earlier["cases"] if r["case"] not in done] + rows
        command = f"{earlier['command']}; {command}"
    write_results(args.name, {"src": args.src, "timeout_s": args.timeout, "command": command, "cases": rows})


if __name__ == "__main__":
    main()
