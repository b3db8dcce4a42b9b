"""Streaming throughput: ``btel localize --stream`` lines per second per input format, start-up subtracted.

For d = 500 and d = 3780 (NetVLAD-PCA-like and HOG-like widths) this script writes ``--lines``
descriptors in each format a camera pipeline produces:

- ``savetxt``: ``numpy.savetxt(f, Q)`` — its default, ``'%.18e'`` separated by single spaces;
- ``savetxt-comma``: ``numpy.savetxt(f, Q, delimiter=",")``;
- ``repr-comma``: the shortest round-trip ``repr`` of each float32 value, comma-separated;
- ``binary``: float32 frames (``--binary``: a uint32 count, then the float32 values).

and measures, in one run:

- **parse**: lines per second of :func:`btel.sequence.lineparse.parse_lines` on blocks of 256 lines (text
  formats), against the parser of before issue #22 (a Python ``float`` per token, ``old_parse``);
- **stream**: :func:`btel.sequence.streaming.localize_stream` over the file opened in binary mode (as the
  CLI does), model prediction included, output discarded;
- **CLI file**: ``btel localize MODEL --stream --input FILE``, stdout to /dev/null, minus the same
  command on an empty file (interpreter start-up and model loading: the start-up);
- **CLI pipe**: the same with the file piped into stdin (``cat FILE | btel localize MODEL --stream``),
  minus the same start-up.

The model is BTE-C (``btel-c``, the paper's method) fitted on a synthetic route of 2,000 places.
The machine's load average is printed beside each row (a shared machine: the lead re-runs it on a
quiet one). The target: ≥ 20,000 lines/s at d = 500 for both savetxt formats through the CLI.

    python benchmarks/bench_stream.py                 # 20,000 lines at d = 500 and 3780
    python benchmarks/bench_stream.py --lines 5000 --dims 500
    python benchmarks/bench_stream.py --before ../main/src   # also another btel tree's CLI, same run

``--before SRC`` also times ``btel localize --stream`` (file and pipe) with the btel package under SRC
(the text formats it reads), start-up subtracted alike: the ratio to it is what a change gained.

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
FORMATS = ("savetxt", "savetxt-comma", "repr-comma", "binary")


def old_parse(line: str, n_features: int) -> np.ndarray:
    """The parser before issue #22: split with a regex, Python float per token, finiteness check."""
    tokens = [t for t in _SEPARATORS.split(line.strip()) if t]
    if len(tokens) != n_features:
        raise ValueError("count")
    values = np.array([float(t) for t in tokens], dtype=np.float64)
    if not np.isfinite(values).all():
        raise ValueError("finite")
    return values.astype(np.float32).reshape(1, -1)


def write_format(path: Path, Q: np.ndarray, fmt: str) -> None:
    if fmt == "savetxt":
        np.savetxt(path, Q)
    elif fmt == "savetxt-comma":
        np.savetxt(path, Q, delimiter=",")
    elif fmt == "repr-comma":
        path.write_text("".join(",".join(repr(v) for v in row.tolist()) + "\n" for row in Q))
    else:
        head = np.uint32(Q.shape[1]).tobytes()
        path.write_bytes(b"".join(head + row.astype("<f4").tobytes() for row in Q))


def best_rate(fn, n: int, repeats: int = 3) -> float:
    best = np.inf
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - start)
    return n / best


def run(d: int, n_lines: int, folder: Path, before: Path | None = None) -> list[dict]:
    from btel import BTELocalizer
    from btel.datasets import synthetic_route
    from btel.sequence.lineparse import parse_lines
    from btel.sequence.streaming import localize_stream

    route = synthetic_route(2000, d, seed=0)
    model = BTELocalizer(progress=False, random_state=0).fit(route.map)
    model_path = folder / f"model{d}.npz"
    model.save(model_path)
    Q = route.queries[np.arange(n_lines) % len(route.queries)]
    expected = model.predict(Q)
    env = {**os.environ, "PYTHONPATH": str(HERE.parent / "src")}
    cli = [sys.executable, "-m", "btel.cli", "localize", str(model_path), "--stream"]
    rows = []
    for fmt in FORMATS:
        data = folder / f"{fmt}{d}.txt"
        write_format(data, Q, fmt)
        flags = ["--binary"] if fmt == "binary" else []
        load = os.getloadavg()
        row = {"d": d, "format": fmt, "lines": n_lines, "bytes_per_line": data.stat().st_size / n_lines,
               "load_before": list(load)}
        if fmt != "binary":
            raw = data.read_bytes().splitlines(keepends=True)
            blocks = [raw[i:i + 256] for i in range(0, len(raw), 256)]
            row["parse_lines_per_s"] = best_rate(lambda: [parse_lines(b, d) for b in blocks], n_lines)
            sample = [line.decode() for line in raw[: max(1, n_lines // 10)]]  # the old parser: a tenth
            old = best_rate(lambda: [old_parse(s, d) for s in sample], len(sample), 1)
            row["old_parse_lines_per_s"] = old
            row["parse_ratio_vs_old"] = row["parse_lines_per_s"] / row["old_parse_lines_per_s"]
            assert np.array_equal(parse_lines(raw[:1], d)[0], old_parse(raw[0].decode(), d))

        def streamed() -> list[int]:
            with open(data, "rb") as source:
                return [place for _, place in localize_stream(model, source, binary=fmt == "binary")]

        assert np.array_equal(streamed(), expected)
        row["stream_lines_per_s"] = best_rate(streamed, n_lines, 1)

        def cli_seconds(path: Path, pipe: bool, env: dict[str, str] = env) -> float:
            start = time.perf_counter()
            if pipe:
                with open(path, "rb") as fh:
                    cat = subprocess.Popen(["cat"], stdin=fh, stdout=subprocess.PIPE)
                    out = subprocess.run(cli + flags, stdin=cat.stdout, check=True, capture_output=True,
                                         env=env)
                    cat.wait()
            else:
                out = subprocess.run(cli + flags + ["--input", str(path)], check=True, capture_output=True,
                                     env=env)
            elapsed = time.perf_counter() - start
            assert len(out.stdout.split()) == (0 if path.stat().st_size == 0 else n_lines)
            return elapsed

        empty = folder / "empty.txt"
        empty.write_bytes(b"")
        for how, pipe in (("file", False), ("pipe", True)):
            startup = min(cli_seconds(empty, pipe) for _ in range(3))
            total = min(cli_seconds(data, pipe) for _ in range(2))
            row[f"cli_{how}_startup_s"], row[f"cli_{how}_total_s"] = startup, total
            row[f"cli_{how}_lines_per_s"] = n_lines / max(total - startup, 1e-9)
        if before is not None and fmt != "binary":
            old_env = {**env, "PYTHONPATH": str(before)}
            for how, pipe in (("file", False), ("pipe", True)):
                startup = min(cli_seconds(empty, pipe, old_env) for _ in range(3))
                total = min(cli_seconds(data, pipe, old_env) for _ in range(2))
                row[f"before_cli_{how}_lines_per_s"] = n_lines / max(total - startup, 1e-9)
                row[f"cli_{how}_ratio_vs_before"] = (row[f"cli_{how}_lines_per_s"]
                                                     / row[f"before_cli_{how}_lines_per_s"])
        row["load_after"] = list(os.getloadavg())
        rows.append(row)
        parse = (f"parse {row['parse_lines_per_s']:>8,.0f}/s ({row['parse_ratio_vs_old']:4.1f}× old)"
                 if "parse_lines_per_s" in row else " " * 31)
        cli_file, cli_pipe = row["cli_file_lines_per_s"], row["cli_pipe_lines_per_s"]
        print(f"d = {d:<5} {fmt:<14} {parse}  stream {row['stream_lines_per_s']:>8,.0f}/s  CLI file "
              f"{cli_file:>8,.0f}/s  pipe {cli_pipe:>8,.0f}/s  (start-up {row['cli_file_startup_s']:.2f} s; "
              f"load {load[0]:.2f} → {row['load_after'][0]:.2f})"
              + (f"; before: CLI file {row['before_cli_file_lines_per_s']:,.0f}/s "
                 f"({row['cli_file_ratio_vs_before']:.2f}×), pipe {row['before_cli_pipe_lines_per_s']:,.0f}/s "
                 f"({row['cli_pipe_ratio_vs_before']:.2f}×)" if "cli_file_ratio_vs_before" in row else ""),
              flush=True)
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--lines", type=int, default=20_000)
    parser.add_argument("--dims", type=int, nargs="+", default=[500, 3780])
    parser.add_argument("--before", type=Path, default=None, help="another btel source tree, timed alike")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        rows = [row for d in args.dims for row in run(d, args.lines, Path(tmp), args.before)]
    path = write_results("bench_stream", {"rows": rows, "targets_lines_per_s": {"500": 20_000},
                                          "command": " ".join(["python", *sys.argv])})
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
