"""RaBitQ's query in float (faiss ``qb = 0``) against the query quantised to 8 and 4 bits, same models.

Each model is fitted once per (map, budget, seed); its faiss index is then searched with ``qb`` set
to 0, 8 and 4 in turn, so the codes are identical and only the query's quantisation differs. Per
setting: recall at the map's key tolerances over every query (one batch) and the median time of one
query (``predict`` of a single row, ``--calls`` rows, one faiss thread). Maps: Gardens Point NetVLAD
both ways (200 places, d = 500, every query), a synthetic route (2,000 × 1,024) and a wide one
(2,000 × 4,096, today's descriptor widths), every 10th query of each.

    python benchmarks/studies/rabitq_query_bits.py            # seeds 0 1 2, about 10 minutes

Writes ``benchmarks/results/rabitq_query_bits.json``; docs/decisions/rabitq.md quotes it.
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import numpy as np

from _common import write_results

SHARED = Path(__file__).resolve().parents[3] / "shared" / "data"
QUERY_BITS = (0, 8, 4)


def maps() -> dict[str, tuple[np.ndarray, np.ndarray, tuple[int, ...]]]:
    from btel.datasets import synthetic_route

    gp = np.load(SHARED / "gardenspoint_netvlad" / "hiddenRepr-GardensPoint.npz")
    out = {"gardens-point": (gp["hlrTrain"], gp["hlrTest"], (0, 2)),
           "gardens-point reversed": (gp["hlrTest"], gp["hlrTrain"], (0, 2))}
    for n, d in ((2000, 1024), (2000, 4096)):
        route = synthetic_route(n, d, seed=0)
        # Every 10th query: the float query's scan takes up to 0.2 s a query at d = 4,096.
        out[f"synthetic route {n}×{d}"] = (route.map, route.queries[::10], (0, 2))
    return out


def main() -> None:
    import faiss

    import btel
    from btel.exceptions import BudgetTooSmallError

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--budgets", default="4KB,64KB,256KB,1MB")
    parser.add_argument("--seeds", default="0,1,2")
    parser.add_argument("--calls", type=int, default=50)
    args = parser.parse_args()
    faiss.omp_set_num_threads(1)
    rows = []
    for name, (X, Q, tolerances) in maps().items():
        truth = np.arange(len(X))[:: len(X) // len(Q)][: len(Q)]
        for budget in args.budgets.split(","):
            for seed in (int(s) for s in args.seeds.split(",")):
                try:
                    model = btel.make_method("rabitq", budget=budget, random_state=seed).fit(X)
                except BudgetTooSmallError:
                    continue
                row = {"map": name, "budget": budget, "seed": seed, "dim": int(model.dim_),
                       "nbits": int(model.nbits_), "load": os.getloadavg()[0]}
                for qb in QUERY_BITS:
                    model._index.qb = qb  # the same codes, the query quantised or not
                    pred = model.predict(Q)
                    for t in tolerances:
                        row[f"qb{qb}_recall@{t}"] = float(np.mean(np.abs(pred - truth) <= t))
                    times = []
                    for i in range(min(args.calls, len(Q))):
                        start = time.perf_counter()
                        model.predict(Q[i:i + 1])
                        times.append(time.perf_counter() - start)
                    row[f"qb{qb}_ms"] = 1e3 * float(np.median(times))
                rows.append(row)
                print(f"{name:28s} {budget:6s} seed {seed} D={row['dim']:<5d} B={row['nbits']} | "
                      + " | ".join(f"qb={qb}: " + " ".join(f"R@{t} {row[f'qb{qb}_recall@{t}']:.3f}" for t in tolerances)
                                   + f" {row[f'qb{qb}_ms']:.2f} ms" for qb in QUERY_BITS)
                      + f"  (load {row['load']:.1f})", flush=True)
    summary = {}
    for qb in QUERY_BITS[1:]:
        diffs = [row[f"qb{qb}_recall@{t}"] - row[f"qb0_recall@{t}"] for row in rows for t in (0, 2)]
        speed = [row["qb0_ms"] / row[f"qb{qb}_ms"] for row in rows]
        summary[f"qb{qb}"] = {"recall_minus_float": {"min": min(diffs), "max": max(diffs),
                                                     "mean": float(np.mean(diffs))},
                              "speed_up": {"min": min(speed), "median": float(np.median(speed)),
                                           "max": max(speed)}}
        print(f"qb={qb} against float: recall difference {min(diffs):+.3f} … {max(diffs):+.3f} "
              f"(mean {np.mean(diffs):+.4f}) over {len(diffs)} figures; one query "
              f"{min(speed):.1f}–{max(speed):.1f}× faster (median {np.median(speed):.1f}×)")
    path = write_results("rabitq_query_bits", {"rows": rows, "summary": summary})
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
