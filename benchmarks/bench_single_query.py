"""Single-query latency of btel against faiss called directly, one thread, timed in one run (issue 35).

Every btel row is timed *interleaved* with its peer: query j goes to the peer, then to btel, then
query j + 1, …, each call timed alone after a warm-up, faiss and BLAS on one thread. The ratio of
the two medians is what the targets are stated in, so the machine's load (printed) shifts both sides.

- **btel-codes vs faiss.IndexFlatIP** on a synthetic route (d = 256, N = 10⁴, 64 KB; target
  ≤ 0.5×). The peer is what a faiss script does: copy the query, ``faiss.normalize_L2``, search.
- **faiss-backed methods** (``pq``, ``opq``, ``itq``, ``rabitq`` at 64 KB, ``bruteforce``
  unbudgeted) against *the model's own faiss index* called directly on the query normalised as
  above and projected as the model projects it (PCA / OPQ rotation / ITQ centring, projection and
  sign packing / RaBitQ rotation, in numpy, as a faiss script would); target ≤ 1.2×.
- **N = 10⁶** (``--large``): btel-codes at 64 KB with periodic and random codes: fit seconds, peak
  fit memory is in ``bench_codes_memory.py``; save, then ``btel.load`` and the first query timed
  together (target ≤ 0.3 s for the first query), then single queries (``predict``; target ≤ 1 ms)
  twice: cold (each query at a new place: the codewords it scores are generated then, as they are
  not stored) and warm (the same queries again, those codewords in the runtime cache),
  their recall@0 / @10 and how often they equal the exact decode (queries at every 1000th place).
  The fitted 10⁶ models are cached under ``--cache`` (the route takes minutes to generate and each
  fit minutes more); load and first query are timed with the modules already imported (import time
  is the start-up's). For the random family, a probe of binary indexes over its packed codewords
  (``--no-probe`` skips it): faiss IndexBinaryFlat's single query and agreement with the exact decode,
  Hamming distances of the exact best codeword, IndexBinaryHNSW's build time on 10⁵ places.

    python benchmarks/bench_single_query.py                # N = 10⁴ rows (≈ 2 min)
    python benchmarks/bench_single_query.py --large        # and the N = 10⁶ rows (first run: fits, ≈ 20 min)

Writes ``benchmarks/results/bench_single_query.json``; without ``--large`` the file's earlier N = 10⁶ rows are
kept, and with ``--large-only`` its N = 10⁴ rows, each with the date it was measured.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path
from typing import Any, Callable

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

from _common import RESULTS_DIR, write_results  # noqa: E402

DIM = 256
BUDGET = "64KB"
FAISS_METHODS = (("pq", BUDGET), ("opq", BUDGET), ("itq", BUDGET), ("rabitq", BUDGET), ("bruteforce", None))


def route(n: int, n_queries: int, strided: bool = False) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(map, queries, their true places): a synthetic route (raw rows: every method normalises them itself);
    the queries at ``n_queries`` sampled places, or at every (N / n_queries)-th place (``strided``)."""
    from btel.datasets import synthetic_route

    r = synthetic_route(n, DIM, seed=0)
    rows = np.arange(0, n, n // n_queries) if strided else \
        np.sort(np.random.default_rng(1).choice(n, size=min(n, n_queries), replace=False))
    return r.map, np.ascontiguousarray(r.queries[rows]), rows


def normalized(q: np.ndarray) -> np.ndarray:
    """A faiss script's query normalisation: a copy, ``faiss.normalize_L2`` in place."""
    import faiss

    q = np.array(q, dtype=np.float32)
    faiss.normalize_L2(q)
    return q


def interleaved(fns: dict[str, Callable[[np.ndarray], Any]], Q: np.ndarray, calls: int) -> dict[str, dict[str, float]]:
    """Microseconds of single-row calls of every function, taking turns query by query (one thread)."""
    from btel.core.threads import limit_threads

    rows = [Q[i % len(Q) : i % len(Q) + 1] for i in range(calls)]
    times = {name: np.empty(calls) for name in fns}
    with limit_threads(1):
        for q in rows[:50]:
            for fn in fns.values():
                fn(q)
        for i, q in enumerate(rows):
            for name, fn in fns.items():
                start = time.perf_counter()
                fn(q)
                times[name][i] = time.perf_counter() - start
    return {name: {"median_us": float(np.median(t) * 1e6), "p90_us": float(np.percentile(t, 90) * 1e6)}
            for name, t in times.items()}


def recall(pred: np.ndarray, truth: np.ndarray) -> dict[str, float]:
    err = np.abs(np.asarray(pred, dtype=np.int64) - truth)
    return {"recall@0": float(np.mean(err == 0)), "recall@10": float(np.mean(err <= 10))}


def faiss_peer(model: Any, name: str) -> Callable[[np.ndarray], Any]:
    """The model's faiss index called directly on the query prepared as the model prepares it."""
    if name == "opq":
        index, projection = model.pq_._index, model.projection_
        return lambda q: index.search(np.ascontiguousarray(normalized(q) @ projection), 1)
    index = model._index
    if name == "pq":
        projection = model.projection_
        if projection is None:
            return lambda q: index.search(normalized(q), 1)
        return lambda q: index.search(np.ascontiguousarray(normalized(q) @ projection), 1)
    if name == "itq":
        mean, projection = model.mean_, model.projection_
        return lambda q: index.search(np.packbits((normalized(q) - mean) @ projection > 0, axis=1), 1)
    if name == "rabitq":
        rotation = model.rotation_
        return lambda q: index.search(np.ascontiguousarray(rotation.apply(normalized(q))), 1)
    return lambda q: index.search(normalized(q), 1)


def small_rows(calls: int) -> list[dict[str, Any]]:
    """N = 10⁴: btel-codes vs IndexFlatIP, each faiss-backed method vs its own index."""
    import faiss

    import btel
    from btel.methods.codes.estimator import CodeLocalizer

    n = 10_000
    X, Q, truth = route(n, 2000)
    flat = faiss.IndexFlatIP(DIM)
    flat.add(normalized(X))
    flat_fn = lambda q: flat.search(normalized(q), 1)  # noqa: E731
    out = []
    for code in ("periodic", "random"):
        model = CodeLocalizer(budget=BUDGET, code=code).fit(X)
        model.predict(Q[:1])
        t = interleaved({"peer": flat_fn, "btel": model.predict}, Q, calls)
        agree = float(np.mean(model.predict(Q) == flat.search(normalized(Q), 1)[1][:, 0]))
        row = {"n_places": n, "method": f"btel-codes {BUDGET} ({code}, path {model.exact_path(1)})",
               "peer": "faiss.IndexFlatIP", "btel_us": t["btel"], "peer_us": t["peer"],
               "ratio": t["btel"]["median_us"] / t["peer"]["median_us"], "target": 0.5 if code == "periodic" else None,
               "bytes": int(model.nbytes), **recall(model.predict(Q), truth), "agrees_with_flat": agree,
               "load": list(os.getloadavg())}
        out.append(row)
        _print(row)
    for name, budget in FAISS_METHODS:
        model = btel.make_method(name, budget=budget).fit(X)
        peer = faiss_peer(model, name)
        same = float(np.mean(np.concatenate([peer(Q[i : i + 1])[1][:, 0] for i in range(200)]) == model.predict(Q[:200])))
        for mode, fn in (("predict", model.predict), ("search k=1", lambda q, model=model: model.search(q, 1))):
            t = interleaved({"peer": peer, "btel": fn}, Q, calls)
            row = {"n_places": n, "method": f"{name} {budget or 'unbudgeted'} {mode}", "peer": f"its faiss index "
                   f"({type(model.pq_._index if name == 'opq' else model._index).__name__}) called directly",
                   "btel_us": t["btel"], "peer_us": t["peer"], "ratio": t["btel"]["median_us"] / t["peer"]["median_us"],
                   "target": 1.2, "bytes": int(model.nbytes), "same_answer_as_peer": same,
                   "configuration": model.summary() or str(getattr(model, "config_", "")), "load": list(os.getloadavg())}
            out.append(row)
            _print(row)
    return out


def _print(row: dict[str, Any]) -> None:
    target = "" if row["target"] is None else f" (target ≤ {row['target']}×)"
    print(f"  N = {row['n_places']:,d} {row['method']:<46} btel {row['btel_us']['median_us']:9.1f} µs  "
          f"peer {row['peer_us']['median_us']:9.1f} µs  ratio {row['ratio']:.3f}×{target}  "
          f"(load {row['load'][0]:.1f})", flush=True)


def large_rows(calls: int, cache: Path, sweep: int = 0, probe: bool = True) -> list[dict[str, Any]]:
    """N = 10⁶: fit (cached), load + first query, single queries of both code families."""
    import btel
    from btel.methods.codes.estimator import CodeLocalizer

    n = 1_000_000
    cache.mkdir(parents=True, exist_ok=True)
    queries_path = cache / "single_query_1m_queries.npz"
    paths = {code: cache / f"single_query_1m_{code}.btel.npz" for code in ("periodic", "random")}
    fit_s: dict[str, float] = {}
    if not queries_path.is_file() or not all(p.is_file() for p in paths.values()):
        print(f"N = {n:,d}: generating the route …", flush=True)
        X, Q, truth = route(n, 1000, strided=True)
        for code, path in paths.items():
            start = time.perf_counter()
            model = CodeLocalizer(budget=BUDGET, code=code).fit(X)
            fit_s[code] = time.perf_counter() - start
            print(f"  fitted {code} in {fit_s[code]:.1f} s: {model.summary()}", flush=True)
            model.save(path)
            del model
        del X
        np.savez(queries_path, queries=Q, truth=truth, **{f"fit_s_{c}": s for c, s in fit_s.items()})
    with np.load(queries_path) as z:
        Q, truth = z["queries"], z["truth"]
        fit_s = {c: float(z[f"fit_s_{c}"]) for c in paths if f"fit_s_{c}" in z}
    import faiss  # noqa: F401  (imports are warm: their time is the start-up's, not the model's)

    btel.load(paths["periodic"]).predict(Q[:1])  # every module a load and a query import
    out = []
    for code, path in paths.items():
        start = time.perf_counter()
        model = btel.load(path)
        load_s = time.perf_counter() - start
        first = model.predict(Q[:1])
        first_s = time.perf_counter() - start
        # Cold: each query at a new place, its candidates' codewords generated as it scores them (not stored);
        # warm: the same queries again, those codewords now in the runtime cache.
        t = interleaved({"btel": model.predict}, Q, calls)["btel"]
        warm = interleaved({"btel": model.predict}, Q, calls)["btel"]
        pred = model.predict(Q)
        row = {"n_places": n, "method": f"btel-codes {BUDGET} ({code})", "fit_s": fit_s.get(code),
               "load_s": load_s, "load_and_first_query_s": first_s, "first_query_s": first_s - load_s,
               "single_us": t, "single_warm_us": warm, "decode": model.decode, "path": "coarse" if model._coarse_plan(1) else model.exact_path(1),
               "bytes": int(model.nbytes), **recall(pred, truth), "load": list(os.getloadavg())}
        if row["path"] == "coarse":
            model.set_params(decode="exact")
            exact = model.predict(Q[:200])
            row["agrees_with_exact"] = float(np.mean(exact == pred[:200]))
        if code == "periodic" and sweep:
            row["block_sweep"] = block_sweep(model, Q[:sweep])
        if code == "random" and probe:
            row["binary_index_probe"] = binary_index_probe(model, Q[:200])
        del first
        out.append(row)
        print(f"  N = {n:,d} {row['method']:<30} load {load_s:.3f} s, load + first query {first_s:.3f} s "
              f"(target first query ≤ 0.3 s), single {t['median_us'] / 1e3:.3f} ms cold / {warm['median_us'] / 1e3:.3f} "
              f"ms warm (target ≤ 1 ms), path {row['path']}, "
              f"R@0 {row['recall@0']:.3f} R@10 {row['recall@10']:.3f}"
              + (f", same as exact {row['agrees_with_exact']:.2f}" if "agrees_with_exact" in row else "")
              + f" (load {row['load'][0]:.1f})", flush=True)
    return out


def binary_index_probe(model: Any, Q: np.ndarray, hnsw_places: int = 100_000) -> dict[str, Any]:
    """Whether a binary index over the random family's packed codewords could stand in for its exact
    decode: faiss IndexBinaryFlat (Hamming to the margins' signs) timed and compared with the exact decode,
    the Hamming distance of the exact best codeword against the nearest and a typical one, and
    IndexBinaryHNSW's build time."""
    import faiss

    from btel.core.threads import limit_threads

    model.set_params(decode="exact")
    exact = model.predict(Q)
    scan, K = model._codewords.adc_index().index, int(model.n_codes_)
    codes = faiss.vector_to_array(scan.codes).reshape(-1, scan.code_size)
    bits = (model._padded_margins(model._check_queries(Q)) >= 0).astype(np.uint8)
    bits[:, K:] = 1  # padding columns: +1 codewords (zero margins), no Hamming distance
    signs = np.packbits(bits, axis=1, bitorder="little")
    with limit_threads(1):
        flat = faiss.IndexBinaryFlat(8 * scan.code_size)
        flat.add(codes)
        single = []
        for i in range(min(50, len(Q))):
            start = time.perf_counter()
            flat.search(signs[i : i + 1], 1)
            single.append(time.perf_counter() - start)
        dist, rows = flat.search(signs, 1000)
        hnsw = faiss.IndexBinaryHNSW(8 * scan.code_size, 16)
        start = time.perf_counter()
        hnsw.add(codes[:hnsw_places])
        hnsw_s = time.perf_counter() - start
    of_exact = np.unpackbits(codes[exact] ^ signs, axis=1).sum(axis=1)
    # The floor of any exact scan: one read of the packed codewords (no arithmetic beyond an OR of
    # 64-bit words, which the memory read bounds), best of 20, the codes out of the caches as a scan finds them.
    words = codes.reshape(-1).view(np.uint64) if codes.size % 8 == 0 else np.frombuffer(
        codes.tobytes()[: codes.size // 8 * 8], dtype=np.uint64)
    read = []
    for _ in range(20):
        start = time.perf_counter()
        np.bitwise_or.reduce(words)
        read.append(time.perf_counter() - start)
    out = {"queries": len(Q), "flat_single_ms": float(np.median(single) * 1e3),
           "code_bytes": int(codes.size), "read_pass_ms": float(np.min(read) * 1e3),
           "flat_top1_same_as_exact": float(np.mean(rows[:, 0] == exact)),
           "exact_in_flat_top1000": float(np.mean((rows == exact[:, None]).any(axis=1))),
           "hamming_exact_best_median": float(np.median(of_exact)),
           "hamming_nearest_median": float(np.median(dist[:, 0])),
           "hamming_typical": K / 2, "bits": K, "hnsw_places": hnsw_places, "hnsw_build_s": hnsw_s,
           "load": list(os.getloadavg())}
    model.set_params(decode="auto")
    print(f"    random codes, binary index over the packed codewords: IndexBinaryFlat "
          f"{out['flat_single_ms']:.2f} ms a query, its top 1 the exact answer "
          f"{out['flat_top1_same_as_exact']:.3f} (exact in its top 1000 {out['exact_in_flat_top1000']:.3f}); "
          f"Hamming of the exact best {out['hamming_exact_best_median']:.0f}, nearest "
          f"{out['hamming_nearest_median']:.0f}, typical {K / 2:.0f} of {K} bits; IndexBinaryHNSW build "
          f"{hnsw_s:.1f} s for {hnsw_places:,d} places; one read of the {out['code_bytes'] / 1e6:.0f} MB of packed "
          f"codewords {out['read_pass_ms']:.2f} ms (load {out['load'][0]:.1f})", flush=True)
    return out


def block_sweep(model: Any, Q: np.ndarray) -> list[dict[str, Any]]:
    """The coarse decode's block B (16 refined blocks) against its warm single-query time and its agreement
    with the exact decode on the same queries: the evidence behind the default B (REFINED_PLACE_COST)."""
    from btel.methods.codes.search import REFINED_PLACE_COST

    model.set_params(decode="exact")
    exact = model.predict(Q)
    model.set_params(decode="coarse")
    n, t = int(model.n_places_), int(model.coarse_candidates)
    default = int(round(np.sqrt(n / (t * REFINED_PLACE_COST))))
    rows = []
    for block in sorted({int(round(np.sqrt(n / t))), default, 500, 707}):
        model.set_params(coarse_block=block)
        pred = model.predict(Q)  # fills the codewords of the blocks these queries refine: warm timings
        timing = interleaved({"btel": model.predict}, Q, 2 * len(Q))["btel"]
        rows.append({"block": block, "candidates": t, "default": block == default, "single_warm_us": timing,
                     "agrees_with_exact": float(np.mean(pred == exact)), "load": list(os.getloadavg())})
        print(f"    B = {block:5d}{' (default)' if block == default else '          '} × {t} blocks refined: "
              f"{timing['median_us']:8.1f} µs warm, same as exact {rows[-1]['agrees_with_exact']:.3f} "
              f"(load {rows[-1]['load'][0]:.1f})", flush=True)
    model.set_params(coarse_block=None, decode="auto")
    return rows


def earlier_rows(large: bool) -> list[dict[str, Any]]:
    """The results file's rows of the other size, kept when this run measures one size only: its
    N = 10⁶ rows (``large``; ``--large`` takes ≈ 20 minutes of fits) or, under ``--large-only``, its
    N = 10⁴ ones; each keeps the date of the run that measured it under ``measured``."""
    path = RESULTS_DIR / "bench_single_query.json"
    if not path.is_file():
        return []
    import json

    earlier = json.loads(path.read_text())
    date = earlier.get("machine", {}).get("date")
    return [{**row, "measured": row.get("measured", date)} for row in earlier.get("rows", [])
            if (row.get("n_places", 0) >= 1_000_000) == large]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--calls", type=int, default=2000, help="single-query calls timed per row")
    parser.add_argument("--large", action="store_true", help="also the N = 10⁶ rows")
    parser.add_argument("--large-only", action="store_true", help="only the N = 10⁶ rows")
    parser.add_argument("--sweep", type=int, default=200, help="queries of the 10⁶ coarse block sweep (0: none)")
    parser.add_argument("--no-probe", action="store_true", help="skip the random family's binary-index probe")
    parser.add_argument("--cache", type=Path, default=RESULTS_DIR / "cache", help="where the 10⁶ models are kept")
    args = parser.parse_args()
    load_before = os.getloadavg()
    today = time.strftime("%Y-%m-%dT%H:%M:%S")
    rows = [] if args.large_only else small_rows(args.calls)
    if args.large or args.large_only:
        rows += large_rows(min(args.calls, 1000), args.cache, args.sweep, not args.no_probe)
    for row in rows:
        row["measured"] = today
    kept = [] if args.large else earlier_rows(large=not args.large_only)
    path = write_results("bench_single_query", {"rows": rows + kept, "load_before": list(load_before),
                                                "load_after": list(os.getloadavg()), "calls": args.calls,
                                                "rows_kept_from_an_earlier_run": len(kept)})
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
