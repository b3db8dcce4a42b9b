"""Shrinkage whitening's basis at 4 bits an entry against int8: brute force on the whitened rows.

For each map of ``btel experiment frontier`` (Gardens Point NetVLAD 500-D and the same rows permuted,
Nordland HOG both directions, the synthetic route and the synthetic independent places) and ranks
r = 4, 8, 16, 32, the shrinkage whitening of :mod:`btel.core.shrink` is fitted on the L2-normalised
map, its eigenvector basis quantised per column to int8 (levels ±127, what files before the 4-bit
basis stored) and to 4 bits (levels ±7, what ``fit_shrink`` stores), and cosine brute force on the
whitened rows is scored by the map's key recall (recall@2 on Gardens Point and the synthetic route,
recall@10 on Nordland, recall@0 on maps of independent places). The basis is the only difference
between the two columns; 4 bits cost half the bytes. One BLAS thread.

    python benchmarks/studies/whitening_shrink_bits.py             # ≈ 1–4 min
    python benchmarks/studies/whitening_shrink_bits.py --quick     # Gardens Point and small synthetic maps

Writes ``benchmarks/results/bench_shrink_bits.json`` and prints the table.
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np
from _common import add_data_arguments, frontier_maps, key_recall, write_results

from btel.core.frontend import normalize_rows
from btel.core.shrink import apply_shrink, fit_shrink
from btel.core.threads import limit_threads

RANKS = (4, 8, 16, 32)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true")
    add_data_arguments(parser)
    args = parser.parse_args()
    start, rows = time.time(), []
    with limit_threads(1):
        for base, X, Q in frontier_maps(args, args.quick):
            Z, ZQ = normalize_rows(X.astype(np.float32), "l2"), normalize_rows(Q.astype(np.float32), "l2")
            for rank in RANKS:
                recall = {}
                for bits, levels in (("int8", 127), ("4-bit", 7)):
                    mean, basis, scale, gains = fit_shrink(Z, rank, levels=levels)
                    A = normalize_rows(apply_shrink(Z, mean, basis, scale, gains), "l2")
                    B = normalize_rows(apply_shrink(ZQ, mean, basis, scale, gains), "l2")
                    recall[bits] = key_recall((B @ A.T).argmax(axis=1), base["key"])
                rows.append({"dataset": base["dataset"], "key": base["key"], "rank": rank,
                             "n_features": int(X.shape[1]), **recall})
                print(f"{base['dataset']:<24} r = {rank:>2} (d = {X.shape[1]:>4})  "
                      f"int8 {recall['int8']:.3f}  "
                      f"4-bit {recall['4-bit']:.3f}  difference {recall['4-bit'] - recall['int8']:+.3f}  "
                      f"({base['key']})", flush=True)
    out = write_results("bench_shrink_bits", {"rows": rows, "quick": args.quick,
                                              "seconds": time.time() - start, "load": os.getloadavg()})
    print(f"wrote {out} ({time.time() - start:.0f} s)")


if __name__ == "__main__":
    main()
