"""Shrinkage whitening's basis at 4 bits an entry against int8: brute force on the whitened rows.

For each map of ``btel experiment frontier`` (Gardens Point NetVLAD 500-D and the same rows permuted,
Nordland HOG both directions, the synthetic route and the synthetic independent places) and ranks
r = 4, 8, 16, 32, the shrinkage whitening of :mod:`btel.shrink` is fitted on the L2-normalised map,
its eigenvector basis quantised per column to int8 (levels ±127, what files before the 4-bit basis
stored) and to 4 bits (levels ±7, what ``fit_shrink`` stores), and cosine brute force on the whitened rows is scored by the map's key
recall (recall@2 on Gardens Point and the synthetic route, recall@10 on Nordland, recall@0 on maps
of independent places). The basis is the only difference between the two columns; 4 bits cost half
the bytes. One BLAS thread.

    python benchmarks/bench_shrink_bits.py             # ≈ 1 min
    python benchmarks/bench_shrink_bits.py --quick     # Gardens Point and small synthetic maps

Writes ``benchmarks/results/bench_shrink_bits.json`` and prints the table.
"""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

import numpy as np

from btel.frontend import normalize_rows
from btel.shrink import apply_shrink, fit_shrink
from btel.threads import limit_threads

HERE = Path(__file__).resolve().parent
RANKS = (4, 8, 16, 32)
TOLERANCE = {"recall@0": 0, "recall@2": 2, "recall@10": 10}


def main() -> None:
    from btel.experiments._common import NordlandData
    from btel.experiments.frontier import _maps

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--data", type=Path, default=HERE.parent.parent / "shared" / "data" / "nordland64")
    parser.add_argument("--cache", type=Path, default=HERE / "results" / "cache")
    args = parser.parse_args()
    start, rows = time.time(), []
    data = NordlandData(args.data, args.cache, progress=False)
    with limit_threads(1):
        for base, X, Q in _maps(data, args.quick):
            tol, truth = TOLERANCE[base["key"]], np.arange(len(Q))
            Z, ZQ = normalize_rows(X.astype(np.float32), "l2"), normalize_rows(Q.astype(np.float32), "l2")
            for rank in RANKS:
                recall = {}
                for bits, levels in (("int8", 127), ("4-bit", 7)):
                    mean, basis, scale, gains = fit_shrink(Z, rank, levels=levels)
                    A = normalize_rows(apply_shrink(Z, mean, basis, scale, gains), "l2")
                    B = normalize_rows(apply_shrink(ZQ, mean, basis, scale, gains), "l2")
                    recall[bits] = float(np.mean(np.abs((B @ A.T).argmax(axis=1) - truth) <= tol))
                rows.append({"dataset": base["dataset"], "key": base["key"], "rank": rank,
                             "n_features": int(X.shape[1]), **recall})
                print(f"{base['dataset']:<24} r = {rank:>2} (d = {X.shape[1]:>4})  int8 {recall['int8']:.3f}  "
                      f"4-bit {recall['4-bit']:.3f}  difference {recall['4-bit'] - recall['int8']:+.3f}  "
                      f"({base['key']})", flush=True)
    out = HERE / "results" / "bench_shrink_bits.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps({"rows": rows, "quick": args.quick, "seconds": time.time() - start,
                               "load": os.getloadavg()}, indent=1) + "\n")
    print(f"wrote {out} ({time.time() - start:.0f} s)")


if __name__ == "__main__":
    main()
