"""What auto's map statistics cost, and what probing fewer rows on wide or long maps changes.

:func:`btel.methods.auto.index_order` ranks each probe row's cosines against the map: the route share
searches every row (up to 65,536) for the nearest one of another place, so it costs probes × N × d
multiply-adds — 2,000 probes of a 10⁴ × 16,384 map are 3.3 · 10¹¹. :func:`~btel.methods.auto.statistics.probe_rows`
keeps probes × rows × d within ``STAT_PRODUCTS`` (2³⁴), down to 500 probes. This study computes
both statistics, the map's kind and the seconds, at 2,000 probes (the rule before) and at
``probe_rows`` probes, on

- every map of ``btel experiment frontier`` (only Nordland, 3,576 × 3,780, is probed by fewer rows);
- synthetic routes of the widths benchmark's shapes, d = 2,048 … 16,384, N = 2,000 and 10,000, with
  their rows in route order and permuted (independent places).

One thread. Writes ``benchmarks/results/auto_statistics_probes.json`` and prints a Markdown table.

    python benchmarks/studies/auto_statistics_probes.py      # ≈ 3 min on one quiet core
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from _common import add_data_arguments, frontier_maps, write_results

from btel.core.threads import limit_threads
from btel.datasets import synthetic_route
from btel.methods.auto import statistics as S
from btel.methods.auto.statistics import index_order

#: (N, d) of the synthetic maps: the widths benchmark's (benchmarks/bench_widths.py).
SHAPES = ((2000, 2048), (2000, 16384), (10000, 2048), (10000, 8192), (10000, 16384))


def measure(X: np.ndarray, probes: int) -> dict:
    start = time.perf_counter()
    order = index_order(X, probes=probes)
    return {"probes": probes, "route_share": order.share, "continuity": order.continuity, "kind": order.kind,
            "seconds": time.perf_counter() - start}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_data_arguments(parser)
    parser.add_argument("--skip-synthetic", action="store_true", help="the frontier's maps only")
    args = parser.parse_args()
    maps = [(base["dataset"], X) for base, X, _ in frontier_maps(args)]
    if not args.skip_synthetic:
        for n, d in SHAPES:
            route = synthetic_route(n, d, condition_shift=1.0, seed=3).map.astype(np.float32)
            maps.append((f"synthetic route {n} × {d}", route))
            perm = np.random.default_rng(0).permutation(n)
            maps.append((f"synthetic permuted {n} × {d}", route[perm]))
    rows, start = [], time.time()
    print("| map | N | d | probes | route share (2,000 → probes) | continuity (2,000 → probes) | kind | seconds (2,000 → probes) |")
    print("| --- | ---: | ---: | ---: | --- | --- | --- | --- |")
    with limit_threads(1):
        for name, X in maps:
            X = np.ascontiguousarray(X, dtype=np.float32)
            n, d = X.shape
            before = measure(X, S.STAT_ROWS)
            probes = S.probe_rows(n, d)
            after = measure(X, probes) if probes != S.STAT_ROWS else before
            rows.append({"map": name, "n": n, "d": d, "before": before, "after": after})
            kind = before["kind"] if before["kind"] == after["kind"] else f"**{before['kind']} → {after['kind']}**"
            print(f"| {name} | {n:,} | {d:,} | {probes:,} | {before['route_share']:.3f} → {after['route_share']:.3f} | "
                  f"{before['continuity']:.3f} → {after['continuity']:.3f} | {kind} | "
                  f"{before['seconds']:.2f} → {after['seconds']:.2f} |", flush=True)
    changed = sum(r["before"]["kind"] != r["after"]["kind"] for r in rows)
    print(f"\nkind changed on {changed} of {len(rows)} maps; {time.time() - start:.0f} s")
    path = write_results("auto_statistics_probes", {"command": "python benchmarks/studies/auto_statistics_probes.py",
                                                    "stat_products": S.STAT_PRODUCTS, "min_probes": S.MIN_STAT_ROWS,
                                                    "rows": rows, "kind_changed": changed})
    print(f"written to {path}")


if __name__ == "__main__":
    main()
