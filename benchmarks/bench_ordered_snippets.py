"""Output codes against LSH on maps in a cone whose order holds only between neighbours: auto's continuity gate.

auto gives an *ordered* map (route share ≥ :data:`~btel.methods.auto.ORDER_SHARE`) periodic output
codes while LSH's effective bits per row are few (:mod:`btel.methods.auto.rule`, step 3). The route
share reads only a row's nearest neighbour, so a map of independent places in which pairs or triples
of alike rows sit next to each other in the index (the NetVLAD sets of the frontier issue have route
shares of 0.14–0.40) looks ordered to it. This benchmark cuts a synthetic route
(``synthetic_route(600, 500, ...)``: the size of the 600-place set at Gardens Point's d = 500; an easy
and a hard change of conditions) into snippets of L consecutive places (L = 600 is the route, 1 a
map of independent places) in random order, map and queries alike, and puts its rows in a cone with
a shared offset (1.5 and 3 × the mean row length: cone ratio ≈ 0.84 and 0.95, where ``lsh`` runs
uncentred at 4 KB and its effective bits fall below the bound). For each map: the route share, the
route continuity (:func:`~btel.methods.auto.route_continuity`), auto's choice, and recall@0 (the
exact place: the only fair tolerance once the index order is shuffled) and recall@2 of periodic and
random output codes and LSH (seeds 0 … ``--seeds`` − 1) at 4 and 8 KB. auto is counted right when it
chose the method with the better recall@0 (recall@2 on the route itself).

    python benchmarks/bench_ordered_snippets.py      # ≈ 1 min on 2 shared cores

Writes ``benchmarks/results/bench_ordered_snippets.json`` and prints the table.
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np
from _common import key_recall, write_results

from btel.datasets import synthetic_route
from btel.frontend import normalize_rows
from btel.methods import make_method
from btel.methods.auto import choose_method, route_continuity, route_share
from btel.methods.baselines.lsh import cone_ratio
from btel.threads import limit_threads

N_PLACES, DIM = 600, 500
SETTINGS = (("easy", 1.0, 0.2), ("hard", 2.5, 0.6))
OFFSETS = (1.5, 3.0)
SNIPPETS = (600, 10, 3, 2, 1)
BUDGETS = (4_000, 8_000)
CANDIDATES = (("lsh", "lsh", {}), ("periodic codes", "btel-codes", {"code": "periodic"}),
              ("random codes", "btel-codes", {"code": "random"}))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=2)
    args = parser.parse_args()
    start, rows = time.time(), []
    with limit_threads(1):
        for setting, shift, noise in SETTINGS:
            route = synthetic_route(N_PLACES, DIM, condition_shift=shift, noise=noise, seed=31)
            direction = np.random.default_rng(9).normal(size=DIM).astype(np.float32)
            direction *= np.linalg.norm(route.map, axis=1).mean() / np.linalg.norm(direction)
            for offset in OFFSETS:
                for length in SNIPPETS:
                    snippets = np.arange(N_PLACES // length * length).reshape(-1, length)
                    order = np.concatenate(snippets[np.random.default_rng(length).permutation(len(snippets))])
                    X, Q = (route.map + offset * direction)[order], (route.queries + offset * direction)[order]
                    cone, share, continuity = cone_ratio(normalize_rows(X)), route_share(X), route_continuity(X)
                    for budget in BUDGETS:
                        values: dict[str, dict[str, float]] = {}
                        for label, name, params in CANDIDATES:
                            runs = [make_method(name, budget=budget, random_state=seed, **params).fit(X).predict(Q)
                                    for seed in range(args.seeds)]
                            values[label] = {key: float(np.mean([key_recall(r, key) for r in runs]))
                                             for key in ("recall@0", "recall@2")}
                        chose = choose_method(X, None, len(X), budget)[0]["method"]
                        key = "recall@2" if length == N_PLACES else "recall@0"
                        codes_won = values["periodic codes"][key] > values["lsh"][key]
                        right = (chose == "btel-codes") == codes_won
                        rows.append({"setting": setting, "offset": offset, "snippet": length, "cone_ratio": cone,
                                     "route_share": share, "continuity": continuity, "budget": budget,
                                     "auto_chose": chose, "judged_by": key, "auto_right": right, **values})
                        print(f"{setting:<4} cone {cone:.2f} snippets of {length:>3}  share {share:.2f}  continuity "
                              f"{continuity:.2f}  {budget // 1000} KB  {key}: lsh {values['lsh'][key]:.3f}  periodic "
                              f"{values['periodic codes'][key]:.3f}  random {values['random codes'][key]:.3f}  "
                              f"auto {chose}{'' if right else ' (the other won)'}", flush=True)
    print(f"auto chose the better of periodic codes and LSH in {sum(r['auto_right'] for r in rows)} of {len(rows)} rows")
    out = write_results("bench_ordered_snippets", {"rows": rows, "seeds": args.seeds, "seconds": time.time() - start,
                                                   "load": os.getloadavg()})
    print(f"wrote {out} ({time.time() - start:.0f} s)")


if __name__ == "__main__":
    main()
