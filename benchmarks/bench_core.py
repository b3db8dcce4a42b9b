"""BTEL fit and query time against exact flat search (faiss.IndexFlatL2), same data, same run.

Default: N = 8192 places, d = 4096, c = 0.1 (d' = 410), r ∈ {1, 20}, on a synthetic route.
Reports per-query predict time in batch and one query at a time, the speed-up over
``IndexFlatL2.search`` (a ratio, robust to machine noise), fit time, bytes and recall@10.

    python benchmarks/bench_core.py            # the issue's configuration
    python benchmarks/bench_core.py --quick    # N = 2048, d = 1024: a smoke run
"""

from __future__ import annotations

import argparse
import time

import faiss
import numpy as np

from btel import BTELocalizer
from btel.datasets import synthetic_route

from _common import write_results


def per_query_seconds(fn, queries: np.ndarray, *, single: int) -> tuple[float, float]:
    """(batch seconds per query, single-query seconds per query over the first ``single`` rows)."""
    start = time.perf_counter()
    fn(queries)
    batch = (time.perf_counter() - start) / len(queries)
    rows = [queries[i : i + 1] for i in range(min(single, len(queries)))]
    start = time.perf_counter()
    for q in rows:
        fn(q)
    one = (time.perf_counter() - start) / len(rows)
    return batch, one


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--places", type=int, default=8192)
    parser.add_argument("--dim", type=int, default=4096)
    parser.add_argument("--feature-ratio", type=float, default=0.1)
    parser.add_argument("--regions", type=int, nargs="+", default=[1, 20])
    parser.add_argument("--n-jobs", type=int, default=-1)
    parser.add_argument("--single", type=int, default=300, help="queries timed one at a time")
    parser.add_argument("--quick", action="store_true", help="N = 2048, d = 1024")
    args = parser.parse_args()
    if args.quick:
        args.places, args.dim = 2048, 1024

    route = synthetic_route(args.places, args.dim, seed=0)
    X, Q = route.map, route.queries
    truth = np.arange(args.places)

    flat = faiss.IndexFlatL2(args.dim)
    start = time.perf_counter()
    flat.add(X)
    flat_fit = time.perf_counter() - start
    flat_search = lambda q: flat.search(q, 1)[1][:, 0]  # noqa: E731
    flat_batch, flat_one = per_query_seconds(flat_search, Q, single=args.single)
    flat_recall = float(np.mean(np.abs(flat_search(Q) - truth) <= 10))

    rows = [{
        "method": "faiss.IndexFlatL2", "regions": None, "fit_s": flat_fit, "bytes": int(X.nbytes),
        "batch_us_per_query": flat_batch * 1e6, "single_us_per_query": flat_one * 1e6,
        "speedup_batch": 1.0, "speedup_single": 1.0, "recall@10": flat_recall,
    }]
    for r in args.regions:
        model = BTELocalizer(feature_ratio=args.feature_ratio, n_regions=r, n_jobs=args.n_jobs, random_state=0)
        start = time.perf_counter()
        model.fit(X)
        fit_s = time.perf_counter() - start
        batch, one = per_query_seconds(model.predict, Q, single=args.single)
        rows.append({
            "method": "BTE-C" if r == 1 else f"BTEL r={r}", "regions": r, "fit_s": fit_s, "bytes": model.nbytes,
            "batch_us_per_query": batch * 1e6, "single_us_per_query": one * 1e6,
            "speedup_batch": flat_batch / batch, "speedup_single": flat_one / one,
            "recall@10": float(np.mean(np.abs(model.predict(Q) - truth) <= 10)),
        })

    print(f"N = {args.places}, d = {args.dim}, c = {args.feature_ratio}, faiss threads = {faiss.omp_get_max_threads()}")
    header = f"{'method':<18} {'fit s':>7} {'bytes':>11} {'batch µs/q':>11} {'1-query µs':>11} {'× flat (batch)':>15} {'× flat (1-q)':>13} {'R@10':>6}"
    print(header)
    print("-" * len(header))
    for row in rows:
        print(f"{row['method']:<18} {row['fit_s']:>7.1f} {row['bytes']:>11,d} {row['batch_us_per_query']:>11.1f} "
              f"{row['single_us_per_query']:>11.1f} {row['speedup_batch']:>15.1f} {row['speedup_single']:>13.1f} "
              f"{row['recall@10']:>6.3f}")
    path = write_results("bench_core" + ("_quick" if args.quick else ""), {"config": vars(args), "rows": rows})
    print(f"written to {path}")


if __name__ == "__main__":
    main()
