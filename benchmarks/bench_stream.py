"""Streaming throughput: ``btel localize --stream`` lines per second, and the parser against the old one.

For d = 500 and d = 3780 (NetVLAD-PCA-like and HOG-like widths) this script writes 10,000
descriptor lines (comma-separated, ``repr`` of float32 values, as ``numpy.savetxt`` or a camera
pipeline would) and measures, in one process:

- **parse only**: lines per second of :func:`btel.streaming.parse_descriptor_line` (orjson from
  the raw bytes) against the previous parser (Python ``float`` per token, reproduced here as
  ``old_parse``), on the same lines, and the ratio;
- **stream**: :func:`btel.streaming.localize_stream` over the file opened in binary mode (as the
  CLI does), model prediction included, output discarded;
- **CLI**: ``btel localize MODEL --stream --input FILE`` in a subprocess, stdout to /dev/null,
  minus the time of the same command on an empty file (interpreter start-up and model loading).

The model is BTEL (``btel-c``, the paper's method) fitted on a synthetic route of 2,000 places.
The machine's load average is printed beside each ratio (a shared machine).

    python benchmarks/bench_stream.py            # 10,000 lines at d = 500 and 3780
    python benchmarks/bench_stream.py --lines 2000

Writes ``benchmarks/results/bench_stream.json``.
"""

from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

from _common import write_results  # noqa: E402

_SEPARATORS = re.compile(r"[,\s]+")


def old_parse(line: str, n_features: int) -> np.ndarray:
    """The parser before issue #22: split with a regex, Python float per token, finiteness check."""
    tokens = [t for t in _SEPARATORS.split(line.strip()) if t]
    if len(tokens) != n_features:
        raise ValueError("count")
    values = np.array([float(t) for t in tokens], dtype=np.float64)
    if not np.isfinite(values).all():
        raise ValueError("finite")
    return values.astype(np.float32).reshape(1, -1)


def lines_per_second(fn, lines, repeats: int = 3) -> float:
    best = np.inf
    for _ in range(repeats):
        start = time.perf_counter()
        for line in lines:
            fn(line)
        best = min(best, time.perf_counter() - start)
    return len(lines) / best


def run(d: int, n_lines: int, folder: Path) -> dict:
    from btel import BTELocalizer
    from btel.datasets import synthetic_route
    from btel.streaming import localize_stream, parse_descriptor_line

    route = synthetic_route(2000, d, seed=0)
    model = BTELocalizer(progress=False, random_state=0).fit(route.map)
    model_path = folder / f"model{d}.npz"
    model.save(model_path)
    Q = route.queries[np.arange(n_lines) % len(route.queries)]
    text = "".join(",".join(repr(v) for v in row.tolist()) + "\n" for row in Q)
    data = folder / f"lines{d}.txt"
    data.write_text(text)
    raw = text.encode().splitlines(keepends=True)
    strs = text.splitlines(keepends=True)
    sample = max(1, n_lines // 5)  # the old parser is slow: a fifth of the lines
    load = os.getloadavg()
    new_parse = lines_per_second(lambda b: parse_descriptor_line(b, d), raw)
    old = lines_per_second(lambda s: old_parse(s, d), strs[:sample])
    assert np.array_equal(parse_descriptor_line(raw[0], d), old_parse(strs[0], d))

    start = time.perf_counter()
    with open(data, "rb") as source:
        answers = [place for _, place in localize_stream(model, source)]
    stream_s = time.perf_counter() - start
    assert len(answers) == n_lines

    empty = folder / "empty.txt"
    empty.write_text("")
    cli = [sys.executable, "-m", "btel.cli", "localize", str(model_path), "--stream", "--input"]
    env = {**os.environ, "PYTHONPATH": str(HERE.parent / "src")}

    def cli_seconds(path: Path) -> float:
        start = time.perf_counter()
        subprocess.run(cli + [str(path)], check=True, stdout=subprocess.DEVNULL, env=env)
        return time.perf_counter() - start

    startup = min(cli_seconds(empty) for _ in range(2))
    cli_total = cli_seconds(data)
    row = {
        "d": d, "lines": n_lines, "load_before": list(load), "load_after": list(os.getloadavg()),
        "parse_lines_per_s": new_parse, "old_parse_lines_per_s": old, "parse_ratio_vs_old": new_parse / old,
        "stream_lines_per_s": n_lines / stream_s,
        "cli_lines_per_s_excluding_startup": n_lines / max(cli_total - startup, 1e-9),
        "cli_startup_s": startup, "cli_total_s": cli_total,
    }
    print(f"d = {d}: parse {new_parse:,.0f} lines/s vs old {old:,.0f} ({new_parse / old:.1f}×); "
          f"localize_stream {row['stream_lines_per_s']:,.0f} lines/s; CLI {row['cli_lines_per_s_excluding_startup']:,.0f}"
          f" lines/s after {startup:.2f} s start-up (load {load[0]:.2f})", flush=True)
    return row


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--lines", type=int, default=10_000)
    parser.add_argument("--dims", type=int, nargs="+", default=[500, 3780])
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        rows = [run(d, args.lines, Path(tmp)) for d in args.dims]
    path = write_results("bench_stream", {"rows": rows, "targets_lines_per_s": {"500": 20_000, "3780": 4_000}})
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
