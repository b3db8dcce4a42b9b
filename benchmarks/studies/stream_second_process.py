"""Would a second process lift the text stream's throughput? savetxt lines parsed beside the main process.

``btel localize --stream`` parses text lines in the main process (:func:`btel.sequence.lineparse.parse_lines`,
orjson per line); the parse is most of its time (``docs/decisions/streaming.md``). This study measures
what a helper process would give on the machine it runs on, with a prototype that keeps only the
throughput-relevant parts of the stream (no error reporting, no ``reset`` lines, no pipes):

- ``one process``: :func:`btel.sequence.streaming.localize_stream` over the file, as shipped;
- ``inline prototype``: the prototype's own loop with no helper (read 1 MiB chunks, split lines, blocks
  of ``--block`` lines, ``parse_lines``, one ``search(rows, 1)`` per block): what the loop costs bare;
- ``helper parses half``: the same loop, every other block sent to a helper process (the block's
  bytes over a pipe; the float32 rows back), the main process parsing the others meanwhile;
- ``helper parses all``: every block sent to the helper, the main process reading, sending and
  predicting only (one block in flight ahead).

Every variant's answers are checked equal to the shipped stream's. BTE-C on a synthetic route of
2,000 places, d = 500, ``--lines`` savetxt lines (``'%.18e'``, spaces), best of ``--repeats``,
interleaved; the helper is started before timing (its start-up is not counted, a stream would pay it
once). The load average is printed: the helper only helps where a core is idle.

    python benchmarks/studies/stream_second_process.py             # ≈ 1 min
    python benchmarks/studies/stream_second_process.py --lines 20000

Writes ``benchmarks/results/stream_second_process.json``.
"""

from __future__ import annotations

import argparse
import multiprocessing as mp
import os
import sys
import tempfile
import time
from pathlib import Path
from typing import Any, Iterator

import numpy as np

from _common import write_results


def blocks_of_lines(path: Path, block: int) -> Iterator[list[bytes]]:
    """Lists of ``block`` lines (bytes, without their newline) of a file read in 1 MiB chunks."""
    rest = b""
    lines: list[bytes] = []
    with open(path, "rb") as f:
        while chunk := f.read(1 << 20):
            parts = (rest + chunk).split(b"\n")
            rest = parts.pop()
            for part in parts:
                lines.append(part)
                if len(lines) == block:
                    yield lines
                    lines = []
    if rest:
        lines.append(rest)
    if lines:
        yield lines


def helper(conn: Any, d: int) -> None:
    """The helper process: a block of lines in (joined bytes), its float32 rows out; None stops it."""
    from btel.sequence.lineparse import parse_lines

    while True:
        data = conn.recv_bytes()
        if not data:
            break
        rows, fast = parse_lines(data.split(b"\n"), d)
        if not all(fast):
            raise SystemExit("a line left the fast path: the prototype handles none")
        conn.send_bytes(np.ascontiguousarray(rows, dtype=np.float32).tobytes())


def inline(model: Any, path: Path, d: int, block: int) -> list[int]:
    from btel.sequence.lineparse import parse_lines

    out: list[int] = []
    for lines in blocks_of_lines(path, block):
        rows, _ = parse_lines(lines, d)
        out.extend(model.search(rows, 1)[1][:, 0].tolist())
    return out


def with_helper(model: Any, path: Path, d: int, block: int, conn: Any, share: str) -> list[int]:
    """Blocks to the helper (every other one, or all, one in flight ahead), answers in input order."""
    from btel.sequence.lineparse import parse_lines

    out: list[int] = []
    pending: list[int] | None = None  # the block the helper holds: its place in the order

    def collect() -> None:
        rows = np.frombuffer(conn.recv_bytes(), dtype=np.float32).reshape(-1, d)
        out.extend(model.search(rows, 1)[1][:, 0].tolist())

    for k, lines in enumerate(blocks_of_lines(path, block)):
        if share == "all" or k % 2 == 1:
            if pending is not None:
                collect()
            conn.send_bytes(b"\n".join(lines))
            pending = k
            continue
        rows, _ = parse_lines(lines, d)
        if pending is not None:  # the helper's block came first in the input
            collect()
            pending = None
        out.extend(model.search(rows, 1)[1][:, 0].tolist())
    if pending is not None:
        collect()
    return out


def main() -> None:
    import btel
    from btel.datasets import synthetic_route
    from btel.sequence.streaming import localize_stream

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--lines", type=int, default=10_000)
    parser.add_argument("--d", type=int, default=500)
    parser.add_argument("--block", type=int, default=256)
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    route = synthetic_route(2000, args.d, seed=0)
    model = btel.make_method("btel-c").fit(route.map)
    rng = np.random.default_rng(0)
    queries = route.queries[rng.integers(0, len(route.queries), args.lines)]
    folder = Path(tempfile.mkdtemp())
    path = folder / "q.txt"
    np.savetxt(path, queries)

    def shipped() -> list[int]:
        with open(path, "rb") as f:
            return [place for _, place in localize_stream(model, f)]

    context = mp.get_context("fork" if sys.platform.startswith("linux") else "spawn")
    ours, theirs = context.Pipe()
    process = context.Process(target=helper, args=(theirs, args.d), daemon=True)
    process.start()
    variants = {
        "one process (localize_stream)": shipped,
        "inline prototype": lambda: inline(model, path, args.d, args.block),
        "helper parses half": lambda: with_helper(model, path, args.d, args.block, ours, "half"),
        "helper parses all": lambda: with_helper(model, path, args.d, args.block, ours, "all"),
    }
    reference = shipped()
    for name, fn in variants.items():
        if fn() != reference:
            raise SystemExit(f"{name}: answers differ from the shipped stream's")
    load = os.getloadavg()
    best = {name: np.inf for name in variants}
    for _ in range(args.repeats):
        for name, fn in variants.items():
            start = time.perf_counter()
            fn()
            best[name] = min(best[name], time.perf_counter() - start)
    load_after = os.getloadavg()
    ours.send_bytes(b"")
    process.join(timeout=10)
    rows = []
    for name, seconds in best.items():
        row = {"variant": name, "lines": args.lines, "d": args.d, "block": args.block,
               "lines_per_s": args.lines / seconds,
               "ratio_vs_one_process": best["one process (localize_stream)"] / seconds,
               "ratio_vs_inline_prototype": best["inline prototype"] / seconds}
        rows.append(row)
        print(f"{name:<32} {row['lines_per_s']:>9,.0f} lines/s  {row['ratio_vs_one_process']:5.2f}× one process  "
              f"{row['ratio_vs_inline_prototype']:5.2f}× the inline prototype", flush=True)
    print(f"load {load[0]:.2f} → {load_after[0]:.2f} on {os.cpu_count()} cores")
    path.unlink()
    folder.rmdir()
    out = write_results("stream_second_process", {"rows": rows, "load": [load[0], load_after[0]],
                                                   "command": " ".join(["python", *sys.argv])})
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
