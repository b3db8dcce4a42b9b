"""Shrinkage whitening's fit at wide descriptors: seconds and memory of :func:`btel.core.shrink.fit_shrink`.

For each (N, d) — Gaussian rows, L2-normalised, rank r = 32 (the rule's cap) — on one thread: the
seconds and the traced peak memory (numpy allocations, tracemalloc) of ``fit_shrink``, which route
it took (randomized SVD, Gram matrix, full SVD; :func:`btel.core.shrink._top_directions`), and for the wide
maps it sends to the Gram matrix the seconds of the full SVD it replaced, on the same rows.

    python benchmarks/studies/shrink_wide_fit.py

Writes ``benchmarks/results/bench_shrink_fit.json``.
"""

from __future__ import annotations

import argparse
import os
import time
import tracemalloc

import numpy as np
from _common import write_results

from btel.core.rows import normalize_rows
from btel.core.shrink import GRAM_VALUES, fit_shrink
from btel.core.threads import limit_threads

SHAPES = ((500, 8192), (500, 16384), (2000, 12288), (10_000, 8192), (10_000, 16384))
RANK = 32


def route(n: int, d: int, k: int = RANK + 1) -> str:
    if k < min(n, d) // 2 and min(n, d) > 500:
        return "randomized SVD"
    return "Gram matrix" if d > n and n * d > GRAM_VALUES else "full SVD"


def main() -> None:
    argparse.ArgumentParser(description=__doc__.split("\n")[0]).parse_args()
    rng = np.random.default_rng(0)
    rows, load, start = [], os.getloadavg(), time.time()
    with limit_threads(1):
        for n, d in SHAPES:
            Z = normalize_rows(rng.standard_normal((n, d), dtype=np.float32), "l2")
            tracemalloc.start()
            tic = time.perf_counter()
            fit_shrink(Z, RANK)
            seconds = time.perf_counter() - tic
            peak = tracemalloc.get_traced_memory()[1]
            tracemalloc.stop()
            row = {"n_rows": n, "d": d, "rank": RANK, "route": route(n, d), "seconds": seconds,
                   "traced_peak": peak, "map_bytes": Z.nbytes}
            if row["route"] == "Gram matrix":
                centred = Z.astype(np.float64) - Z.mean(axis=0, dtype=np.float64)
                tic = time.perf_counter()
                np.linalg.svd(centred, full_matrices=False)
                row["full_svd_seconds"] = time.perf_counter() - tic
                del centred
            rows.append(row)
            before = f"; full SVD {row['full_svd_seconds']:.2f} s" if "full_svd_seconds" in row else ""
            print(f"N {n:>6} d {d:>6}: {row['route']:<15} {seconds:6.2f} s, traced peak {peak / 1e6:6.0f} MB "
                  f"(map {Z.nbytes / 1e6:.0f} MB){before}", flush=True)
            del Z
    out = write_results("bench_shrink_fit", {"rows": rows, "load": load, "load_end": os.getloadavg(),
                                             "seconds": time.time() - start})
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
