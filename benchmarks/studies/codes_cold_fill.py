"""The 10⁶-place periodic model's cold single query against another btel tree's, processes alternated.

A cold query (each at a new place) generates the packed codewords of the blocks it refines
(:meth:`btel.methods.codes.codewords.Codewords.fill`); a warm one finds them cached. This study loads
``bench_single_query.py --large``'s cached periodic model (N = 10⁶, 64 KB; run that benchmark first)
in a fresh process per pass, answers its 1,000 queries one at a time twice (cold, then warm), one
faiss and one BLAS thread, and alternates the processes of this tree and of ``--before SRC`` (another
checkout's ``src``) ``--pairs`` times, so that both see the same machine. Medians and means of the
per-query times; the load is printed beside each pass.

    python benchmarks/studies/codes_cold_fill.py --before /tmp/old/src --pairs 3

Writes ``benchmarks/results/codes_cold_fill.json``.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np

from _common import write_results

HERE = Path(__file__).resolve().parent
CACHE = HERE.parent / "results" / "cache"

ONE_PASS = r"""
import json, os, sys, time
import numpy as np
import btel, faiss, threadpoolctl
faiss.omp_set_num_threads(1)
threadpoolctl.threadpool_limits(1)
cache = sys.argv[1]
with np.load(os.path.join(cache, "single_query_1m_queries.npz")) as z:
    Q = z["queries"]
btel.load(os.path.join(cache, "single_query_1m_periodic.btel.npz")).predict(Q[:1])  # imports, not timed
model = btel.load(os.path.join(cache, "single_query_1m_periodic.btel.npz"))
model.predict(Q[:1])
out = {"load": os.getloadavg()[0]}
for name in ("cold", "warm"):
    times = []
    for q in Q[1:]:
        start = time.perf_counter()
        model.predict(q[None])
        times.append(time.perf_counter() - start)
    out[name + "_median_ms"] = float(np.median(times) * 1e3)
    out[name + "_mean_ms"] = float(np.mean(times) * 1e3)
print(json.dumps(out))
"""


def one_pass(src: Path) -> dict:
    env = {**os.environ, "PYTHONPATH": str(src)}
    done = subprocess.run([sys.executable, "-c", ONE_PASS, str(CACHE)], env=env, capture_output=True, text=True,
                          check=True)
    return json.loads(done.stdout.strip().splitlines()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--before", type=Path, required=True, help="the other tree's src folder")
    parser.add_argument("--pairs", type=int, default=3)
    args = parser.parse_args()
    if not (CACHE / "single_query_1m_periodic.btel.npz").exists():
        sys.exit(f"no cached 10⁶ model under {CACHE}: run `python benchmarks/bench_single_query.py --large` first.")
    trees = {"this tree": HERE.parent.parent / "src", "before": args.before}
    passes = []
    for pair in range(args.pairs):
        order = list(trees) if pair % 2 == 0 else list(trees)[::-1]
        for name in order:
            row = {"tree": name, "pair": pair, **one_pass(trees[name])}
            passes.append(row)
            print(f"  {name:9s} cold median {row['cold_median_ms']:.3f} ms, mean {row['cold_mean_ms']:.3f} | "
                  f"warm median {row['warm_median_ms']:.3f}, mean {row['warm_mean_ms']:.3f} (load {row['load']:.1f})",
                  flush=True)
    summary = {}
    for name in trees:
        rows = [p for p in passes if p["tree"] == name]
        summary[name] = {key: float(np.mean([r[key] for r in rows]))
                         for key in ("cold_median_ms", "cold_mean_ms", "warm_median_ms", "warm_mean_ms")}
    for key in summary["this tree"]:
        print(f"  {key}: this tree {summary['this tree'][key]:.3f} / before {summary['before'][key]:.3f} "
              f"= {summary['this tree'][key] / summary['before'][key]:.3f}")
    print("wrote", write_results("codes_cold_fill", {"before": str(args.before), "passes": passes,
                                                     "mean_over_pairs": summary}))


if __name__ == "__main__":
    main()
