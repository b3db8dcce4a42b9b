"""LSH on shrinkage-whitened rows against plain LSH, by bits per row against the dimension (P/d).

Whitening flattens the map's spectrum: the rows' variance spreads over many more directions, and a
P-bit sign sketch estimates angles with an error of about 1/√P whatever the dimension. Brute force
gains from the flattening; LSH with few bits against d can lose. This measures where, at the same
budget (the whitening's arrays come out of it): ``lsh`` and ``lsh whiten="shrink"`` (asymmetric
scoring, its default projection) under seeds 0 … ``--seeds`` − 1, on

- a high-dimensional synthetic map (d = 2048, N = 2000, ``synthetic_route(condition_shift=2.5,
  noise=0.6, seed=21)``) as a route (recall@2) and with map and query rows permuted alike (recall@0);
- the maps of ``btel experiment frontier`` (``--frontier``; their figures are also in its table).

P is the plain LSH's bits per row (8 · budget / N). One BLAS and one faiss thread.

    python benchmarks/studies/auto_rule_lsh_whitening.py               # ≈ 4 min on 2 shared cores
    python benchmarks/studies/auto_rule_lsh_whitening.py --frontier    # and the frontier's maps

Writes ``benchmarks/results/bench_lsh_whitening.json`` and prints the table.
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np
from _common import add_data_arguments, frontier_maps, key_recall, paired_difference, signed, write_results

from btel.datasets import synthetic_route
from btel.exceptions import BudgetTooSmallError
from btel.methods import make_method
from btel.core.shrink import shrink_rank
from btel.core.storage import parse_budget
from btel.core.threads import limit_threads


def high_dimensional_maps() -> list[tuple[dict, np.ndarray, np.ndarray, tuple[str, ...]]]:
    route = synthetic_route(2000, 2048, condition_shift=2.5, noise=0.6, seed=21)
    perm = np.random.default_rng(5).permutation(2000)
    budgets = ("32KB", "64KB", "128KB", "256KB", "512KB")
    return [({"dataset": "synthetic 2048-D route", "key": "recall@2"}, route.map, route.queries, budgets),
            ({"dataset": "synthetic 2048-D independent", "key": "recall@0"}, route.map[perm], route.queries[perm],
             budgets)]


def recall(params: dict, X: np.ndarray, Q: np.ndarray, budget: str, seed: int, key: str) -> float | None:
    try:
        model = make_method("lsh", budget=budget, random_state=seed, **params).fit(X)
    except BudgetTooSmallError:
        return None
    return key_recall(model.predict(Q), key)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=3)
    parser.add_argument("--frontier", action="store_true", help="also the frontier experiment's maps")
    add_data_arguments(parser)
    args = parser.parse_args()
    start, rows = time.time(), []
    maps = high_dimensional_maps()
    if args.frontier:
        maps += [(base, X, Q, ("4KB", "16KB", "64KB", "256KB", "1MB")) for base, X, Q in frontier_maps(args)]
    with limit_threads(1):
        for base, X, Q, budgets in maps:
            n, d = X.shape
            for budget in budgets:
                if parse_budget(budget) > n * d * 4:  # larger than the map itself, as the frontier skips
                    continue
                values = {kind: [recall(params, X, Q, budget, seed, base["key"])
                                 for seed in range(args.seeds)]
                          for kind, params in (("plain", {}), ("shrink", {"whiten": "shrink"}))}
                if any(v is None for vs in values.values() for v in vs):
                    continue
                bits = 8 * parse_budget(budget) / n
                row = {"dataset": base["dataset"], "key": base["key"], "budget": budget, "n_features": d,
                       "n_rows": n, "bits_per_row": bits, "bits_per_dimension": bits / d,
                       "shrink_rank": shrink_rank(d, n, parse_budget(budget)), **values,
                       **paired_difference(values["shrink"], values["plain"])}
                rows.append(row)
                print(f"{base['dataset']:<30} {budget:>6} P/d = {bits / d:5.2f} (rank {row['shrink_rank']:>2})  "
                      f"plain {np.mean(values['plain']):.3f}  shrink {np.mean(values['shrink']):.3f}  "
                      f"shrink − plain {signed(row)}  ({base['key']})", flush=True)
    out = write_results("bench_lsh_whitening", {"rows": rows, "seeds": args.seeds, "seconds": time.time() - start,
                                                "load": os.getloadavg()})
    print(f"wrote {out} ({time.time() - start:.0f} s)")


if __name__ == "__main__":
    main()
