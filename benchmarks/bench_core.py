"""BTEL query speed against faiss at matched recall, same data, same run.

Default: a synthetic route, N = 8192 places, d = 4096; BTE-C (c = 0.1, d' = 410) and BTEL r = 20.
Peers, fitted on the same (L2-normalised) map in the same run:

- ``faiss.IndexFlatIP`` — exact cosine search, the recall ceiling;
- **LSH** (binary codes): b seeded Gaussian directions (regenerable from the seed, so not counted
  in bytes), a place's code sign(x·R) (b bits), a query scored asymmetrically, (q·R) against the
  ±1 codes; b swept over ``--lsh-bits``;
- ``faiss.IndexPQ`` (M × 8 bit) for several M, and ``faiss.IndexIVFPQ`` (nlist cells, M × 8 bit)
  for several M and nprobe: the quantisers swept so that each BTEL model can be compared with the
  *cheapest* PQ / IVF-PQ configuration reaching at least its recall@10 (matched recall), not only
  with exact search.

Every method runs at its fastest setting for the mode measured: single queries with faiss and
BLAS on one thread (``btel.core.threads.limit_threads(1)``), batches at the faster of one thread and the
libraries' defaults; no process-wide OpenMP setting.

Timing (every figure): a warm-up call, then ``--repeats`` batch calls over all queries (min and
median reported) and ``--single`` one-query calls each timed on its own (median and 90th
percentile), after 50 warm-up calls. Every timed function does the same work: the queries are
L2-normalised inside it for faiss as BTEL's front end does for BTEL (BTEL's ``predict`` also
validates its input). Recall@10 is top-1 within 10 places, as in the experiments.

The NaN/inf check of the queries: with the normalising front end it runs inside the norm pass;
its share of a batch ``predict`` is measured as (predict with the check) − (predict without it,
``check_finite=False`` on a model whose front end does not check) over the same queries.

    python benchmarks/bench_core.py            # the issue's configuration (~5 min on a quiet machine)
    python benchmarks/bench_core.py --quick    # N = 2048, d = 1024: a smoke run

Writes ``benchmarks/results/bench_core.json`` and prints the tables with the load average.
"""

from __future__ import annotations

import os
import argparse
import sys
import time
from pathlib import Path
from typing import Any, Callable

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

from _common import write_results  # noqa: E402


def time_batch(fn: Callable[[np.ndarray], Any], Q: np.ndarray, repeats: int) -> dict[str, float]:
    """Microseconds per query of ``fn(Q)``: min and median of ``repeats`` calls after one warm-up,
    at the faster (median) of one faiss/BLAS thread and the libraries' default threads."""
    from btel.core.threads import limit_threads

    best: dict[str, Any] | None = None
    for threads in (1, None):
        with limit_threads(threads):
            fn(Q)
            times = []
            for _ in range(repeats):
                start = time.perf_counter()
                fn(Q)
                times.append(time.perf_counter() - start)
        per_query = np.asarray(times) / len(Q) * 1e6
        row = {"batch_us_min": float(per_query.min()), "batch_us_median": float(np.median(per_query)),
               "batch_qps_median": float(1e6 / np.median(per_query)), "batch_threads": threads or "default"}
        if best is None or row["batch_us_median"] < best["batch_us_median"]:
            best = row
    return best


def time_single(fn: Callable[[np.ndarray], Any], Q: np.ndarray, calls: int) -> dict[str, float]:
    """Microseconds of ``fn(q)`` on one-row queries, each call timed on its own (after 50 warm-up calls),
    faiss and BLAS on one thread."""
    from btel.core.threads import limit_threads

    rows = [Q[i % len(Q) : i % len(Q) + 1] for i in range(calls)]
    times = np.empty(calls)
    with limit_threads(1):
        for q in rows[:50]:
            fn(q)
        for i, q in enumerate(rows):
            start = time.perf_counter()
            fn(q)
            times[i] = time.perf_counter() - start
    return {"single_us_median": float(np.median(times) * 1e6), "single_us_p90": float(np.percentile(times, 90) * 1e6)}


def recall10(pred: np.ndarray, truth: np.ndarray) -> float:
    return float(np.mean(np.abs(np.asarray(pred, dtype=np.int64) - truth) <= 10))


def faiss_rows(X: np.ndarray, Q: np.ndarray, truth: np.ndarray, args: argparse.Namespace) -> list[dict[str, Any]]:
    """Exact search, PQ and IVF-PQ over their sweeps, each fitted, scored and timed."""
    import faiss

    from btel.core.frontend import normalize_rows

    d = X.shape[1]
    Xn = normalize_rows(X)
    configs: list[tuple[str, dict[str, Any], Callable[[], Any]]] = [("faiss.IndexFlatIP (exact)", {}, lambda: faiss.IndexFlatIP(d))]
    for m in args.pq_m:
        if d % m == 0:
            configs.append((f"faiss.IndexPQ M={m}", {"M": m}, lambda m=m: faiss.IndexPQ(d, m, 8, faiss.METRIC_INNER_PRODUCT)))
    nlist = args.nlist
    for m in args.ivf_m:
        if d % m == 0:
            configs.append((f"faiss.IndexIVFPQ nlist={nlist} M={m}", {"M": m, "nlist": nlist},
                            lambda m=m: faiss.IndexIVFPQ(faiss.IndexFlatIP(d), d, nlist, m, 8,
                                                         faiss.METRIC_INNER_PRODUCT)))
    rows = []
    for name, params, make in configs:
        index = make()
        start = time.perf_counter()
        if not index.is_trained:
            index.train(Xn)
        index.add(Xn)
        fit_s = time.perf_counter() - start
        if hasattr(index, "pq"):
            nbytes = int(index.sa_code_size() * len(X) + faiss.vector_to_array(index.pq.centroids).nbytes)
            if "IVF" in name:
                nbytes += int(nlist * d * 4 + len(X) * 8)  # coarse centroids + ids
        else:
            nbytes = int(Xn.nbytes)
        probes = args.nprobe if "IVF" in name else [None]
        for nprobe in probes:
            if nprobe is not None:
                index.nprobe = nprobe

            def search(q: np.ndarray, index: Any = index) -> np.ndarray:
                return index.search(normalize_rows(q), 1)[1][:, 0]

            row = {"method": name + ("" if nprobe is None else f" nprobe={nprobe}"),
                   "family": "exact" if "Flat" in name else ("ivfpq" if "IVF" in name else "pq"),
                   "params": {**params, **({"nprobe": nprobe} if nprobe else {})}, "fit_s": fit_s, "bytes": nbytes,
                   "recall@10": recall10(search(Q), truth)}
            row.update(time_batch(search, Q, args.repeats))
            row.update(time_single(search, Q, args.single))
            rows.append(row)
            print(f"  {row['method']:<40} R@10 {row['recall@10']:.3f}  batch {row['batch_us_median']:8.2f} µs/q  "
                  f"single {row['single_us_median']:8.1f} µs", flush=True)
    return rows


def lsh_rows(X: np.ndarray, Q: np.ndarray, truth: np.ndarray, args: argparse.Namespace) -> list[dict[str, Any]]:
    """Sign random projection (seeded), asymmetric scoring, for every b in ``--lsh-bits``."""
    from btel.core.frontend import normalize_rows

    Xn = normalize_rows(X)
    rows = []
    for bits in args.lsh_bits:
        start = time.perf_counter()
        R = np.random.default_rng(0).standard_normal((X.shape[1], bits)).astype(np.float32)
        C = np.where(Xn @ R > 0, np.float32(1), np.float32(-1))
        fit_s = time.perf_counter() - start

        def search(q: np.ndarray, R: np.ndarray = R, C: np.ndarray = C) -> np.ndarray:
            return np.argmax((normalize_rows(q) @ R) @ C.T, axis=1)

        row = {"method": f"LSH {bits}-bit", "family": "lsh", "params": {"bits": bits}, "fit_s": fit_s,
               "bytes": int(len(X) * -(-bits // 8)), "note": "projection regenerable from its seed (not counted)",
               "recall@10": recall10(search(Q), truth)}
        row.update(time_batch(search, Q, args.repeats))
        row.update(time_single(search, Q, args.single))
        rows.append(row)
        print(f"  {row['method']:<40} R@10 {row['recall@10']:.3f}  batch {row['batch_us_median']:8.2f} µs/q  "
              f"single {row['single_us_median']:8.1f} µs  {row['bytes']:,d} B", flush=True)
    return rows


def btel_rows(X: np.ndarray, Q: np.ndarray, truth: np.ndarray, args: argparse.Namespace) -> list[dict[str, Any]]:
    from btel import BTELocalizer
    from btel.core.validation import check_descriptors

    rows = []
    for r in args.regions:
        model = BTELocalizer(feature_ratio=args.feature_ratio, n_regions=r, n_jobs=args.n_jobs, random_state=0,
                             progress=False)
        start = time.perf_counter()
        model.fit(X)
        fit_s = time.perf_counter() - start
        row = {"method": "BTE-C" if r == 1 else f"BTEL r={r}", "family": "btel", "params": {"n_regions": r},
               "fit_s": fit_s, "bytes": int(model.nbytes), "recall@10": recall10(model.predict(Q), truth),
               "n_unconverged": model.n_unconverged_, "solvers": list(model.fit_summary_.solvers)}
        row.update(time_batch(model.predict, Q, args.repeats))
        row.update(time_single(model.predict, Q, args.single))
        # Share of the validation in a batch predict: the old separate NaN/inf pass, and what is
        # left of it now that the front end's norm pass does it.
        separate = time_batch(lambda q: check_descriptors(q, name="Q"), Q, args.repeats)["batch_us_median"]
        row["separate_finiteness_check_us"] = separate
        row["separate_check_share_of_predict"] = separate / (row["batch_us_median"] + separate)
        rows.append(row)
        print(f"  {row['method']:<40} R@10 {row['recall@10']:.3f}  batch {row['batch_us_median']:8.2f} µs/q  "
              f"single {row['single_us_median']:8.1f} µs  fit {fit_s:.1f} s", flush=True)
    return rows


def matched(btel: list[dict[str, Any]], peers: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """For every BTEL row and quantiser family, the fastest configuration with recall@10 ≥ BTEL's."""
    out = []
    for row in btel:
        for family in ("lsh", "pq", "ivfpq", "exact"):
            for key in ("batch_us_median", "single_us_median"):
                ok = [p for p in peers if p["family"] == family and p["recall@10"] >= row["recall@10"]]
                if not ok:
                    out.append({"btel": row["method"], "family": family, "timing": key, "peer": None})
                    continue
                best = min(ok, key=lambda p: p[key])
                out.append({"btel": row["method"], "btel_recall@10": row["recall@10"], "family": family, "timing": key,
                            "peer": best["method"], "peer_recall@10": best["recall@10"], "peer_bytes": best["bytes"],
                            "btel_bytes": row["bytes"], "btel_us": row[key], "peer_us": best[key],
                            "btel_speedup": best[key] / row[key]})
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--places", type=int, default=8192)
    parser.add_argument("--dim", type=int, default=4096)
    parser.add_argument("--feature-ratio", type=float, default=0.1)
    parser.add_argument("--regions", type=int, nargs="+", default=[1, 20])
    parser.add_argument("--n-jobs", type=int, default=-1)
    parser.add_argument("--repeats", type=int, default=7, help="batch calls timed (after one warm-up)")
    parser.add_argument("--single", type=int, default=1000, help="one-query calls timed")
    parser.add_argument("--pq-m", type=int, nargs="+", default=[4, 8, 16, 32, 64])
    parser.add_argument("--ivf-m", type=int, nargs="+", default=[8, 16, 32])
    parser.add_argument("--nlist", type=int, default=64)
    parser.add_argument("--lsh-bits", type=int, nargs="+", default=[16, 32, 64, 128, 256, 512])
    parser.add_argument("--nprobe", type=int, nargs="+", default=[1, 2, 4, 8, 16])
    parser.add_argument("--quick", action="store_true", help="N = 2048, d = 1024, fewer repeats")
    args = parser.parse_args()
    if args.quick:
        args.places, args.dim, args.repeats, args.single, args.nlist = 2048, 1024, 3, 200, 32
    import faiss

    from btel.datasets import synthetic_route

    load_before = os.getloadavg()
    route = synthetic_route(args.places, args.dim, seed=0)
    X, Q = route.map, route.queries
    truth = np.arange(args.places)
    print(f"N = {args.places}, d = {args.dim}, c = {args.feature_ratio}, {len(Q)} queries, faiss threads "
          f"{faiss.omp_get_max_threads()}, load average {load_before[0]:.1f}", flush=True)
    ours = btel_rows(X, Q, truth, args)
    peers = lsh_rows(X, Q, truth, args) + faiss_rows(X, Q, truth, args)
    pairs = matched(ours, peers)
    load_after = os.getloadavg()

    print("\nmatched recall: the fastest peer configuration with recall@10 ≥ BTEL's (speed-up = peer µs / BTEL µs)")
    print(f"{'BTEL':<12} {'R@10':>6} {'bytes':>10} {'timing':<17} {'peer':<44} {'R@10':>6} {'bytes':>10} "
          f"{'BTEL µs':>9} {'peer µs':>9} {'× BTEL':>7}  load")
    for p in pairs:
        if p["peer"] is None:
            print(f"{p['btel']:<12} {'':>6} {p['timing']:<17} no {p['family']} configuration reaches BTEL's recall")
            continue
        print(f"{p['btel']:<12} {p['btel_recall@10']:>6.3f} {p['btel_bytes']:>10,d} {p['timing']:<17} {p['peer']:<44} "
              f"{p['peer_recall@10']:>6.3f} {p['peer_bytes']:>10,d} {p['btel_us']:>9.2f} {p['peer_us']:>9.2f} "
              f"{p['btel_speedup']:>7.1f}  {os.getloadavg()[0]:.2f}")
    for row in ours:
        print(f"{row['method']}: a separate NaN/inf pass would cost {row['separate_finiteness_check_us']:.2f} µs/query, "
              f"{100 * row['separate_check_share_of_predict']:.0f} % of predict plus that pass; now done in the "
              "front end's norm pass")
    print(f"load average before {load_before[0]:.2f}, after {load_after[0]:.2f} (1-min), {os.cpu_count()} cores")
    path = write_results("bench_core" + ("_quick" if args.quick else ""),
                         {"config": vars(args), "load_before": list(load_before), "load_after": list(load_after),
                          "faiss_threads": faiss.omp_get_max_threads(), "btel": ours, "peers": peers,
                          "matched_recall": pairs})
    print(f"written to {path}")


if __name__ == "__main__":
    main()
