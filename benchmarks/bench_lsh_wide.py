"""Wide descriptors: ``lsh`` and ``auto`` fit, load, first query, memory and recall at issue 35's cells.

Cells: d = 8192, N = 500, 1 MB and d = 12,288, N = 2000, 256 KB (the widths of SALAD and BoQ
descriptors), on ``benchmarks/bench_widths.py``'s maps (rows sharing a common direction and a low-rank
part plus noise) with every row's near duplicate as a query; measured as that benchmark does (fit and
save in one forked process; then, in another, load, first query, the next 10 single queries,
resident-memory growth from before the load to after the first query, recall@0), on one thread. Then:

- **refusal from shapes**: ``lsh`` with 64 KB on N = 10⁶ rows of d = 256 (a 1 GB map): the seconds
  and the memory (traced peak; resident growth) until the BudgetTooSmallError;
- **the projection before**: regenerating ``projection="orthogonal"`` (a QR of a d × d block per d
  bits, what every fit and load of the first cell did before) against ``"hadamard"`` (``--no-before``
  skips its 1–2 minutes).

    python benchmarks/bench_lsh_wide.py

Writes ``benchmarks/results/bench_lsh_wide.json``.
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
import tracemalloc

import numpy as np
from _common import write_results
from bench_widths import fit_and_save, in_child, load_and_query, make_data, resident_bytes

from btel.exceptions import BudgetTooSmallError
from btel.methods.baselines.lsh import LSHLocalizer, make_projection
from btel.core.threads import limit_threads

CELLS = ((500, 8192, "1MB"), (2000, 12288, "256KB"))


def refusal(n_rows: int = 10**6, d: int = 256, budget: str = "64KB") -> dict:
    """Seconds and memory until ``lsh`` refuses a budget its smallest code cannot meet."""
    X = np.ones((n_rows, d), dtype=np.float32)
    before = resident_bytes()
    tracemalloc.start()
    tic = time.perf_counter()
    try:
        LSHLocalizer(budget=budget).fit(X)
        message = "fitted (not refused)"
    except BudgetTooSmallError as exc:
        message = str(exc)[:160]
    seconds = time.perf_counter() - tic
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    return {"n_rows": n_rows, "d": d, "budget": budget, "map_bytes": X.nbytes, "seconds": seconds,
            "traced_peak": peak, "resident_growth": resident_bytes() - before, "message": message}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--no-before", action="store_true")
    args = parser.parse_args()
    rows, load, start = [], os.getloadavg(), time.time()
    with limit_threads(1), tempfile.TemporaryDirectory() as tmp:
        tiny, tiny_queries = make_data(64, 32)
        for method in ("lsh", "auto"):  # imports, before any figure
            fit_and_save(method, "1MB", tiny, os.path.join(tmp, f"warm-{method}.npz"))
            load_and_query(os.path.join(tmp, f"warm-{method}.npz"), tiny_queries)
        for n_rows, d, budget in CELLS:
            X, _ = make_data(n_rows, d)
            Q = X + 0.5 * np.random.default_rng(1).standard_normal(X.shape, dtype=np.float32)
            for method in ("lsh", "auto"):
                path = os.path.join(tmp, "m.npz")
                row = {"n_rows": n_rows, "d": d, "budget": budget, "method": method,
                       **in_child(fit_and_save, (method, budget, X, path), 600)}
                row.update(in_child(load_and_query, (path, Q, os.path.join(tmp, f"warm-{method}.npz")), 600))
                rows.append(row)
                print(f"d {d:>6} N {n_rows:>5} {budget:>6} {method:<5} fit {row['fit_s']:6.2f} s  "
                      f"load {row['load_s']:6.3f} s  first {row['first_ms']:7.1f} ms  "
                      f"next {row['next_ms']:6.2f} ms  stored {row['stored'] / 1e3:6.0f} KB  "
                      f"resident +{row['resident'] / 1e6:5.1f} MB  recall {row['recall']:.3f}  "
                      f"({row.get('chose') or method})", flush=True)
        refused = refusal()
        print(f"refusal: N = {refused['n_rows']:,}, d = {refused['d']} ({refused['map_bytes'] / 1e9:.1f} GB "
              f"map), {refused['budget']}: {refused['seconds']:.2f} s, traced peak "
              f"{refused['traced_peak'] / 1e6:.2f} MB, resident +{refused['resident_growth'] / 1e6:.0f} MB — "
              f"{refused['message'][:90]}", flush=True)
        before = None
        if not args.no_before:
            n_rows, d, budget = CELLS[0]
            before = {"d": d, "n_bits": 8192}
            for kind in ("orthogonal", "hadamard"):
                tic = time.perf_counter()
                make_projection(d, 8192, 0, kind)
                before[f"{kind}_s"] = time.perf_counter() - tic
            print(f"projection d = {d}, P = 8192: orthogonal (QR) {before['orthogonal_s']:.1f} s, "
                  f"hadamard {before['hadamard_s'] * 1e3:.1f} ms", flush=True)
    out = write_results("bench_lsh_wide", {"rows": rows, "refusal": refused, "before": before, "load": load,
                                           "load_end": os.getloadavg(), "seconds": time.time() - start})
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
