"""Fit memory: what ``fit`` holds above the map, per method, with the default L2 front end and without it.

A map of ``--places`` rows of width ``--dims`` (independent unit-variance Gaussian rows, float32) is
written to a ``.npy`` file; then, for every method of ``--methods`` and each front end, a fresh
process loads the map into memory, resets its peak resident memory (``/proc/self/clear_refs``; Linux),
fits the method at ``--budget``, and reports the peak (``VmHWM``) minus the resident memory before
the fit: the fit's own peak above the map. The front ends:

- ``l2`` — the default: rows L2-normalised by the front end (a method whose fit reads the map in
  row blocks takes it unscaled, one factor per row; any other fits on a normalised copy);
- ``none`` — the rows normalised beforehand, passed with ``normalize='none'`` (no copy by the front end).

The fit time is printed beside each row; the load average before and after. Writes
``benchmarks/results/bench_fit_memory.json`` (``--out``: another name). The children import btel as
the parent's environment does, so ``PYTHONPATH=OTHER/src`` measures another source tree alike::

    python benchmarks/bench_fit_memory.py                          # lsh and btel-codes, 2·10⁵ × 1024 (≈ 2 min)
    python benchmarks/bench_fit_memory.py --methods lsh pq --places 100000
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

from _common import write_results  # noqa: E402

MB = 1 << 20

# The fit in a fresh process whose map is already in memory: its peak above that is the fit's own.
_FIT = """
import json, os, sys, time
import numpy as np
import btel
path, method, normalize, budget = sys.argv[1], sys.argv[2], sys.argv[3], sys.argv[4]

def status(field):
    with open("/proc/self/status") as f:
        return next(int(line.split()[1]) * 1024 for line in f if line.startswith(field + ":"))

X = np.load(path)
with open("/proc/self/clear_refs", "w") as f:
    f.write("5")  # the peak (VmHWM) from here on: ru_maxrss would keep the parent's and np.load's
rss_before = status("VmRSS")
start = time.perf_counter()
model = btel.make_method(method, budget=budget, normalize=normalize, random_state=0).fit(X)
fit_s = time.perf_counter() - start
peak_after = status("VmHWM")
print(json.dumps({"method": method, "normalize": normalize, "fit_s": fit_s, "map_bytes": int(X.nbytes),
                  "rss_before_fit": rss_before, "peak_after_fit": peak_after,
                  "fit_peak_above_map_bytes": peak_after - rss_before, "model_bytes": int(model.nbytes),
                  "summary": model.summary()}))
"""


def child(code: str, *args: str) -> dict:
    """Run ``code`` in a fresh Python process; its stdout's last line, parsed."""
    proc = subprocess.run([sys.executable, "-c", code, *args], check=False, capture_output=True, text=True)
    if proc.returncode != 0:
        raise RuntimeError(f"child failed: {proc.stderr[-3000:]}")
    return json.loads(proc.stdout.strip().splitlines()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--places", type=int, default=200_000)
    parser.add_argument("--dims", type=int, default=1024)
    parser.add_argument("--budget", default="4MB")
    parser.add_argument("--methods", nargs="+", default=["lsh", "btel-codes"])
    parser.add_argument("--out", default="bench_fit_memory", help="results file name in benchmarks/results")
    args = parser.parse_args()
    load_before = os.getloadavg()
    rows = []
    with tempfile.TemporaryDirectory() as folder:
        raw, unit = str(Path(folder) / "map.npy"), str(Path(folder) / "map_l2.npy")
        X = np.random.default_rng(0).standard_normal((args.places, args.dims), dtype=np.float32)
        np.save(raw, X)
        X /= np.linalg.norm(X, axis=1, keepdims=True)
        np.save(unit, X)  # the rows normalised beforehand, for normalize='none'
        del X
        print(f"map: {args.places:,} × {args.dims} float32 ({args.places * args.dims * 4 / MB:.0f} MB), "
              f"budget {args.budget}")
        for method in args.methods:
            for normalize in ("l2", "none"):
                row = child(_FIT, raw if normalize == "l2" else unit, method, normalize, args.budget)
                rows.append(row)
                print(f"  {method:<12} normalize={normalize:<5} fit {row['fit_s']:6.1f} s  peak "
                      f"{row['fit_peak_above_map_bytes'] / MB:7.0f} MB above the {row['map_bytes'] / MB:.0f} MB map",
                      flush=True)
    load_after = os.getloadavg()
    print(f"load {load_before[0]:.2f} → {load_after[0]:.2f}")
    out = write_results(args.out, {"places": args.places, "dims": args.dims, "budget": args.budget,
                                              "rows": rows, "load_before": list(load_before),
                                              "load_after": list(load_after),
                                              "command": " ".join(["python", *sys.argv])})
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
