"""Do query timings agree between identical runs? (issue 23: one un-warmed call gave 3.1–450 µs.)

Runs ``btel.evaluation.evaluate`` — the harness of ``btel evaluate``, ``btel demo`` and the
experiments — ``--runs`` times on the same data (a fresh fit each run, as a user re-running a
command gets) and reports, per method, the batch throughput (median of 5 warm calls) and the
single-query latency of every run and the spread max/min across runs. The old measurement (one
un-warmed ``predict`` call) is timed in the same runs as the peer.

    python benchmarks/bench_timing_stability.py                # Gardens Point NetVLAD, 3 runs
    python benchmarks/bench_timing_stability.py --runs 5

Writes benchmarks/results/bench_timing_stability.json.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import write_results  # noqa: E402

DATA = Path(__file__).resolve().parents[2] / "shared" / "data" / "gardenspoint_netvlad" / "hiddenRepr-GardensPoint.npz"
METHODS = {"pq": "32KB", "itq": "32KB", "btel-codes": "32KB", "btel-c": "32KB", "bruteforce": None}


def main() -> None:
    from btel.evaluation import evaluate
    from btel.methods import make_method

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=3)
    args = parser.parse_args()
    with np.load(DATA, allow_pickle=False) as data:
        X, Q = data["hlrTrain"].astype(np.float32), data["hlrTest"].astype(np.float32)
    rows = {}
    for name, budget in METHODS.items():
        batch, latency, cold = [], [], []
        for _ in range(args.runs):
            method = make_method(name, **({"budget": budget} if budget else {}))
            if "progress" in method.get_params():
                method.set_params(progress=False)
            method.fit(X)
            start = time.perf_counter()
            method.predict(Q)  # the old measurement: one un-warmed batch call
            cold.append((time.perf_counter() - start) / Q.shape[0])
            result = evaluate(method, None, Q, fit=False, name=name)
            batch.append(result.query_time_s_per_query)
            latency.append(result.query_latency_s)
        rows[name] = {"batch_us": [b * 1e6 for b in batch], "latency_us": [v * 1e6 for v in latency],
                      "one_cold_call_us": [c * 1e6 for c in cold],
                      "batch_spread": max(batch) / min(batch), "latency_spread": max(latency) / min(latency),
                      "cold_spread": max(cold) / min(cold), "n_threads": result.n_threads}
    print(f"{'method':<11} {'batch µs/q per run':<28} {'spread':>6}  {'1-query µs per run':<28} {'spread':>6}  "
          f"{'one cold call (old)':<28} {'spread':>6}")
    for name, r in rows.items():
        def fmt(values: list[float]) -> str:
            return " / ".join(f"{v:.1f}" for v in values)
        print(f"{name:<11} {fmt(r['batch_us']):<28} {r['batch_spread']:6.2f}  {fmt(r['latency_us']):<28} "
              f"{r['latency_spread']:6.2f}  {fmt(r['one_cold_call_us']):<28} {r['cold_spread']:6.2f}")
    path = write_results("bench_timing_stability", {"data": "Gardens Point NetVLAD (200 × 500)", "runs": args.runs,
                                                    "rows": rows})
    print(f"written {path}")


if __name__ == "__main__":
    main()
