"""Output codes at scale: fit and query time of btel-codes against faiss flat search and PQ, same run.

On a synthetic route (d = 256, rows L2-normalised for every method, as every btel method's front end
does) at N = 10,000 and N = 1,000,000 places, this script measures in one process:

- **btel-codes** (periodic codes at 64 KB and 256 KB: the planner's K × d' at 4 bits): fit seconds;
  query time with the exact decode (every place scored: faiss' scan over the codewords expanded
  into packed bits at the first query) and with the coarse-to-fine decode (blocks of places scored
  by their mean codeword, the best blocks refined; ``decode='coarse'``), the one-time cost of each
  cache, and how often the coarse answer equals the exact one;
- **faiss.IndexFlatIP** and **faiss.IndexFlatL2** (exact search, N·d·4 bytes): add time, query time;
- **faiss.IndexPQ** (32 sub-quantisers × 8 bits, trained on 65,536 rows): train + add time, query time;

each with recall within 0 and 10 frames on the same queries (query j of the second traverse is
place j). Query time is reported two ways: a batch (``--batch`` queries in one call; per-query
time = call time / batch) and single queries (each call timed alone, after a warm-up). Each figure
is the minimum and the median over ``--repeats`` repeats (batch) or over the single calls.

    python benchmarks/bench_codes.py              # N = 10k and 1M (≈ 15–25 min on 2 shared cores)
    python benchmarks/bench_codes.py --quick      # N = 10k and 100k, a smoke run
    python benchmarks/bench_codes.py --docs-only  # the docs/results.md section from the saved JSON
    python benchmarks/bench_codes.py --real-only  # Gardens Point and Nordland against flat search

Writes ``benchmarks/results/bench_codes.json`` and the section of ``docs/results.md`` between
``<!-- bench-codes:start -->`` and ``<!-- bench-codes:end -->``.
"""

from __future__ import annotations

import os
import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any, Callable

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

from _common import RESULTS_DIR, machine, write_results  # noqa: E402
from btel.core.storage import format_bytes  # noqa: E402
from btel.datasets.sources import gardens_point_path, load_gardens_point_netvlad  # noqa: E402

DIM = 256
BUDGETS = ("64KB", "256KB")
PQ_M = 32
SECTION = ("<!-- bench-codes:start -->", "<!-- bench-codes:end -->")


def route(n: int, n_queries: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(map, sampled queries, their true places): a synthetic route, rows L2-normalised."""
    from btel.datasets import synthetic_route
    from btel.core.frontend import normalize_rows

    r = synthetic_route(n, DIM, seed=0)
    rows = np.sort(np.random.default_rng(1).choice(n, size=min(n, n_queries), replace=False))
    X = normalize_rows(r.map)
    Q = normalize_rows(np.ascontiguousarray(r.queries[rows]))
    del r
    return X, Q, rows


def timed(fn: Callable[[], Any]) -> tuple[Any, float]:
    start = time.perf_counter()
    out = fn()
    return out, time.perf_counter() - start


def batch_times(fn: Callable[[np.ndarray], np.ndarray], Q: np.ndarray, repeats: int) -> dict[str, float]:
    """Per-query seconds of one call on the whole batch: min and median over repeats (after a warm-up).

    Each method at its fastest setting: timed with faiss and BLAS on one thread and on their
    defaults (every core), the faster median kept (``threads`` says which).
    """
    from btel.core.threads import limit_threads

    best: dict[str, Any] | None = None
    for threads in (1, None):
        with limit_threads(threads):
            fn(Q[:4])
            times = [timed(lambda: fn(Q))[1] / len(Q) for _ in range(repeats)]
        row = {"min": float(np.min(times)), "median": float(np.median(times)), "threads": threads or "default"}
        if best is None or row["median"] < best["median"]:
            best = row
    return best


def single_times(fn: Callable[[np.ndarray], np.ndarray], Q: np.ndarray, calls: int) -> dict[str, float]:
    """Seconds of single-query calls, each timed alone: min and median (after 5 warm-up calls).

    One faiss and one BLAS thread for every method (the fastest setting for one query here:
    faiss' flat search at N = 10⁶ took 46 ms on one thread against 203 ms on two, issue #22).
    """
    from btel.core.threads import limit_threads

    with limit_threads(1):
        for i in range(min(5, len(Q))):
            fn(Q[i : i + 1])
        times = [timed(lambda i=i: fn(Q[i % len(Q) : i % len(Q) + 1]))[1] for i in range(calls)]
    return {"min": float(np.min(times)), "median": float(np.median(times)), "threads": 1}


def lsh_peer(X: np.ndarray, n_bits: int, seed: int = 0) -> tuple[Callable[[np.ndarray], np.ndarray], int]:
    """Sign random projection (LSH) with asymmetric scoring: (predict, bytes of the codes).

    b seeded Gaussian directions R (d × b; regenerable from the seed, so not counted), a place's
    code is sign(x·R) (b bits stored), a query scores place i by (q·R) · c_i, the float query against
    the ±1 code. The codes are expanded to float32 here for the product (memory, not storage).
    """
    R = np.random.default_rng(seed).standard_normal((X.shape[1], n_bits)).astype(np.float32)
    C = np.where(X @ R > 0, np.float32(1), np.float32(-1))

    def predict(q: np.ndarray) -> np.ndarray:
        return np.argmax((q @ R) @ C.T, axis=1)

    return predict, X.shape[0] * -(-n_bits // 8)


def recall(pred: np.ndarray, truth: np.ndarray) -> dict[str, float]:
    err = np.abs(np.asarray(pred, dtype=np.int64) - truth)
    return {"recall@0": float(np.mean(err == 0)), "recall@10": float(np.mean(err <= 10))}


def measure(n: int, n_queries: int, batch: int, repeats: int, single_calls: int) -> list[dict[str, Any]]:
    import faiss

    from btel.methods.codes.estimator import CodeLocalizer

    print(f"N = {n:,d}: generating the route …", flush=True)
    X, Q, truth = route(n, n_queries)
    out: list[dict[str, Any]] = []

    def record(method: str, nbytes: int, fit_s: float, predict: Callable[[np.ndarray], np.ndarray],
               **extra: Any) -> dict[str, Any]:
        pred = predict(Q)
        row = {"n_places": n, "method": method, "bytes": int(nbytes), "fit_s": fit_s,
               "batch_s_per_query": batch_times(predict, Q[:batch], repeats),
               "single_s": single_times(predict, Q, single_calls), **recall(pred, truth), **extra}
        out.append(row)
        print(f"  {method:<34} {nbytes:>12,d} B  fit {fit_s:8.2f} s  batch {row['batch_s_per_query']['median'] * 1e6:9.1f} "
              f"µs/q  single {row['single_s']['median'] * 1e3:8.2f} ms  R@0 {row['recall@0']:.3f} "
              f"R@10 {row['recall@10']:.3f}", flush=True)
        return row

    for budget in (BUDGETS if n < 1_000_000 else BUDGETS[:1]):  # 10⁶: 64 KB only (a 256 KB fit takes minutes)
        # normalize='none': the rows are normalised here once, for every method alike.
        model, fit_s = timed(lambda: CodeLocalizer(budget=budget, normalize="none", decode="exact").fit(X))
        print(f"  btel-codes {budget}: {model.summary()}", flush=True)
        # The first query builds the block bounds and fills the packed codewords of the blocks it scores.
        _, first_s = timed(lambda: model.predict(Q[:1]))
        record(f"btel-codes {budget}, exact (auto: {model.exact_path(1)} single / {model.exact_path(len(Q))} batch)",
               model.nbytes, fit_s, model.predict, first_query_s=first_s, configuration=model.summary(),
               block=model._codewords.decoder().block)
        exact_pred = model.predict(Q)
        margins = model._padded(model._margins(model._check_queries(Q)))
        # 'dense' without the float32 cache (large N) regenerates every codeword per query: not a contender.
        for path in ("bounded", "dense", "scan") if model._codewords.dense() is not None else ("bounded", "scan"):
            fn = (lambda q, path=path: model._exact_search(model._padded(model._margins(model._check_queries(q))),
                                                          1, path)[1][:, 0])
            agree = float(np.mean(model._exact_search(margins, 1, path)[1][:, 0] == exact_pred))
            record(f"btel-codes {budget}, exact by {path}", model.nbytes, fit_s, fn, agrees_with_exact=agree)
        model.set_params(decode="coarse")  # an inference setting: the fitted weights are unchanged
        _, cache_s = timed(lambda: model.predict(Q[:1]))  # builds the block-mean cache once
        block, candidates = model._coarse_shape()
        agree = float(np.mean(model.predict(Q) == exact_pred))
        record(f"btel-codes {budget}, coarse-to-fine decode", model.nbytes, fit_s, model.predict, block=block,
               candidates=candidates, block_mean_cache_s=cache_s, agrees_with_exact=agree,
               configuration=model.summary())
        n_bits = max(8, (model.nbytes * 8 // n) // 8 * 8)
        lsh, lsh_bytes = lsh_peer(X, n_bits)
        record(f"LSH {n_bits}-bit sign projection, asymmetric (≈ {budget})", lsh_bytes, 0.0, lsh,
               note="projection regenerable from its seed (not counted)")

    for name, index_cls in (("faiss.IndexFlatIP", faiss.IndexFlatIP), ("faiss.IndexFlatL2", faiss.IndexFlatL2)):
        index = index_cls(DIM)
        _, add_s = timed(lambda: index.add(X))
        record(name, n * DIM * 4, add_s, lambda q, index=index: index.search(q, 1)[1][:, 0])
        index.reset()  # frees the copy of the map before the next index

    pq = faiss.IndexPQ(DIM, PQ_M, 8)
    sample = X[np.random.default_rng(2).choice(n, size=min(n, 65_536), replace=False)]

    def train_add() -> None:
        pq.train(np.ascontiguousarray(sample))
        for a in range(0, n, 262_144):
            pq.add(X[a : a + 262_144])

    _, pq_s = timed(train_add)
    pq_bytes = pq.sa_code_size() * n + faiss.vector_to_array(pq.pq.centroids).nbytes
    record(f"faiss.IndexPQ ({PQ_M}×8 bit)", pq_bytes, pq_s, lambda q: pq.search(q, 1)[1][:, 0])
    return out


def real_rows(single_calls: int, repeats: int) -> list[dict[str, Any]]:
    """btel-codes at 64 KB and 500 KB against faiss.IndexFlatIP on Gardens Point (NetVLAD) and Nordland (HOG).

    The map and queries of ``../shared/data`` (Nordland: HOG of every frame, summer map, winter
    queries, cached as in the tests); recall@10 = top-1 within 10 places (Gardens Point: 2). Flat
    search gets the queries L2-normalised inside the timed call, as btel's front end does.
    """
    import faiss

    from btel.methods.codes.estimator import CodeLocalizer
    from btel.core.frontend import normalize_rows

    data_root = HERE.parent.parent / "shared" / "data"
    if not data_root.is_dir():
        data_root = Path("/work/shared/data")
    sets = []
    gp = gardens_point_path(data_root)
    if gp.is_file():
        sets.append(("Gardens Point (NetVLAD)", *load_gardens_point_netvlad(gp), 2))
    nordland = data_root / "nordland64"
    if nordland.is_dir():
        import tempfile

        from btel.datasets.nordland import NordlandData

        cache = Path(os.environ.get("BTEL_TEST_CACHE", Path(tempfile.gettempdir()) / "btel-test-cache"))
        X, Q = NordlandData(nordland, cache, progress=False).pair("hog")
        sets.append(("Nordland (HOG)", np.asarray(X, np.float32), np.asarray(Q, np.float32), 10))
    out = []
    for name, X, Q, tol in sets:
        truth = np.arange(len(Q))
        flat = faiss.IndexFlatIP(X.shape[1])
        flat.add(normalize_rows(X))
        flat_fn = lambda q, flat=flat: flat.search(normalize_rows(q), 1)[1][:, 0]  # noqa: E731
        rows = {"faiss.IndexFlatIP": (flat_fn, int(X.nbytes))}
        for budget in ("64KB", "500KB"):
            model = CodeLocalizer(budget=budget).fit(X)
            model.predict(Q[:1])
            rows[f"btel-codes {budget} ({model.exact_path(1)} single)"] = (model.predict, model.nbytes)
        load = os.getloadavg()
        timed_rows = {}
        for method, (fn, nbytes) in rows.items():
            pred = fn(Q)
            timed_rows[method] = {"data": name, "method": method, "bytes": nbytes, "n_places": len(X),
                                  "recall": float(np.mean(np.abs(pred - truth) <= tol)), "tolerance": tol,
                                  "single_s": single_times(fn, Q, single_calls),
                                  "batch_s_per_query": batch_times(fn, Q, repeats)}
        base = timed_rows["faiss.IndexFlatIP"]
        for r in timed_rows.values():
            r["single_vs_flat"] = r["single_s"]["median"] / base["single_s"]["median"]
            r["batch_vs_flat"] = r["batch_s_per_query"]["median"] / base["batch_s_per_query"]["median"]
            r["load"] = list(load)
            print(f"  {name:<24} {r['method']:<34} {r['bytes']:>12,d} B  single {r['single_s']['median'] * 1e6:8.1f} µs "
                  f"({r['single_vs_flat']:.2f}× flat)  batch {r['batch_s_per_query']['median'] * 1e6:8.1f} µs/q "
                  f"({r['batch_vs_flat']:.2f}× flat)  recall {r['recall']:.3f}  (load {load[0]:.2f})", flush=True)
            out.append(r)
    return out


def print_ratios(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Single-query latency of every row against faiss.IndexFlatIP's in the same run, with the load now."""
    flat = next(r for r in rows if r["method"] == "faiss.IndexFlatIP")
    load = os.getloadavg()
    out = []
    for r in rows:
        ratio = r["single_s"]["median"] / flat["single_s"]["median"]
        out.append({"n_places": r["n_places"], "method": r["method"], "single_vs_flat": ratio,
                    "batch_vs_flat": r["batch_s_per_query"]["median"] / flat["batch_s_per_query"]["median"],
                    "load": list(load)})
        print(f"  ratio N = {r['n_places']:,d} {r['method']:<60} single {ratio:6.3f}× flat  "
              f"batch {out[-1]['batch_vs_flat']:6.3f}× flat  (load {load[0]:.2f})", flush=True)
    return out


def section(payload: dict[str, Any]) -> str:
    rows = payload["rows"]
    lines = [SECTION[0], "## Output codes at scale (btel-codes vs faiss, same run)", "",
             f"Synthetic route, d = {DIM}, rows L2-normalised for every method; btel-codes at "
             f"{' and '.join(payload['budgets'])} (periodic codes, the planner's choice). Measured on {payload['machine']['cpu_count']} cores on "
             f"{payload['machine']['date'][:10]} by `python benchmarks/bench_codes.py` (load average "
             f"{payload['load_before'][0]:.1f} before, {payload['load_after'][0]:.1f} after: the machine was shared, "
             f"so timings are upper bounds); `benchmarks/results/bench_codes.json`. Query times: a batch of "
             f"{payload['batch']} queries in one call (per query), and single calls; min / median.", "",
             "| N | method | bytes | fit / build s | batch µs/query (min / med) | single query ms (min / med) | R@0 | R@10 |",
             "| ---: | --- | ---: | ---: | ---: | ---: | ---: | ---: |"]
    for r in rows:
        b, s = r["batch_s_per_query"], r["single_s"]
        lines.append(f"| {r['n_places']:,d} | {r['method']} | {format_bytes(r['bytes'])} | {r['fit_s']:.2f} | "
                     f"{b['min'] * 1e6:,.1f} / {b['median'] * 1e6:,.1f} | {s['min'] * 1e3:,.2f} / {s['median'] * 1e3:,.2f} | "
                     f"{r['recall@0']:.3f} | {r['recall@10']:.3f} |")
    lines.append("")
    for r in rows:
        if "first_query_s" in r:
            lines.append(f"- N = {r['n_places']:,d}, {r['configuration']}; its first query (block bounds, packed "
                         f"codewords of the blocks it scores) took {r['first_query_s']:.3f} s.")
        if "block_mean_cache_s" in r:
            lines.append(f"- N = {r['n_places']:,d}, {r['method']}: blocks of {r['block']} places, "
                         f"{r['candidates']} blocks refined: the same answer as the exact decode for "
                         f"{r['agrees_with_exact']:.1%} of the queries; its block-mean cache took "
                         f"{r['block_mean_cache_s']:.1f} s to build (once per model).")
    lines.append("")
    lines.append("Single-query latency against faiss.IndexFlatIP (one thread each), load average at the time:")
    lines.append("")
    for q in payload.get("ratios", []):
        if q["method"].startswith(("btel-codes", "LSH", "faiss.IndexPQ")):
            lines.append(f"- N = {q['n_places']:,d}, {q['method']}: {q['single_vs_flat']:.3f}× (batch "
                         f"{q['batch_vs_flat']:.3f}×; load {q['load'][0]:.1f})")
    lines += ["", SECTION[1]]
    return "\n".join(lines)


def write_section(text: str) -> Path:
    path = HERE.parent / "docs" / "results.md"
    current = path.read_text() if path.is_file() else ""
    if SECTION[0] in current:
        head, rest = current.split(SECTION[0], 1)
        current = head + text + rest.split(SECTION[1], 1)[1]
    else:
        current = current.rstrip("\n") + "\n\n" + text + "\n"
    path.write_text(current)
    return path


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true", help="N = 10k and 100k only")
    parser.add_argument("--docs-only", action="store_true", help="rewrite the docs section from the saved JSON")
    parser.add_argument("--queries", type=int, default=1000, help="queries sampled along the route")
    parser.add_argument("--batch", type=int, default=200, help="queries per batch call")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--single", type=int, default=30, help="single-query calls timed")
    parser.add_argument("--sizes", type=int, nargs="+", help="map sizes N (default 10k, 100k, 1M; --quick: 10k, 100k)")
    parser.add_argument("--real-only", action="store_true",
                        help="only Gardens Point and Nordland (written to bench_codes_real.json)")
    parser.add_argument("--out", help="results file name in benchmarks/results (default bench_codes, "
                        "bench_codes_real with --real-only); the docs section is only written by the default")
    args = parser.parse_args()
    if args.docs_only:
        payload = json.loads((RESULTS_DIR / "bench_codes.json").read_text())
        print(write_section(section(payload)))
        return
    if args.real_only:
        rows = real_rows(args.single * 5, args.repeats)
        print(f"wrote {write_results(args.out or 'bench_codes_real', {'rows': rows, 'load_after': list(os.getloadavg())})}")
        return
    load_before = os.getloadavg()
    start = time.perf_counter()
    rows = []
    sizes = args.sizes or ((10_000, 100_000) if args.quick else (10_000, 100_000, 1_000_000))
    ratios = []
    for n in sizes:
        block = measure(n, args.queries, args.batch, args.repeats, args.single)
        rows += block
        ratios += print_ratios(block)
        write_results("bench_codes_partial", {"rows": rows, "ratios": ratios})  # kept if a later N is cut short
    payload = {"rows": rows, "ratios": ratios, "dim": DIM, "budgets": list(BUDGETS), "batch": args.batch, "repeats": args.repeats,
               "single_calls": args.single, "queries": args.queries, "quick": args.quick,
               "seconds": time.perf_counter() - start, "load_before": list(load_before),
               "load_after": list(os.getloadavg()), "machine": machine()}
    path = write_results(args.out or "bench_codes", payload)
    print(f"wrote {path}")
    if not args.quick and not args.out:
        print(write_section(section(payload)))


if __name__ == "__main__":
    main()
