"""Output codes against LSH on ordered maps in a cone: the test of auto's effective-bits condition.

Synthetic routes (``synthetic_route(condition_shift, noise, seed=31)``, an easy and a hard change of
conditions) of three shapes — N = 2000 at d = 1024 (8, 16, 32 KB), and N = 600 and N = 210 (the sizes
of the NetVLAD sets of the frontier issue) at Gardens Point's d = 500 (4, 8 KB and 4 KB) — get a shared offset
added to every map and query row (0, 1, 1.5 and 3 × the mean row length), which puts the rows in a
cone (cone ratio of :func:`btel.methods.baselines.lsh.cone_ratio` ≈ 0.24 → 0.73 → 0.84 → 0.95).
Where ``lsh`` cannot afford its mean (more than 1/8 of the budget) it runs uncentred, and each of its
P bits carries :func:`~btel.methods.baselines.lsh.sign_bit_entropy` of the cone ratio. Both ``lsh``
and ``btel-codes`` (periodic) run under seeds 0 … ``--seeds`` − 1; recall@2. Each row also prints
LSH's effective bits per row over the birthday bound 2·log2 N and what auto chose
(:mod:`btel.methods.auto`, step 3: output codes below :data:`~btel.methods.auto.ORDER_BITS_FACTOR`
× the bound); the summary counts the rows where that was the better of the two, apart for the
maps whose route share reaches auto's route branch (the easy N = 210 route, 0.60).

    python benchmarks/studies/auto_rule_cone_route.py      # ≈ 1 min on 2 shared cores

Writes ``benchmarks/results/bench_cone_route.json`` and prints the table.
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np
from _common import cone_direction, key_recall, write_results

from btel.datasets import synthetic_route
from btel.core.frontend import normalize_rows
from btel.methods import make_method
from btel.methods.auto import ROUTE_SHARE, choose_method, collision_bits, route_share
from btel.methods.baselines.lsh import LSHLocalizer, cone_ratio
from btel.core.threads import limit_threads

SETTINGS = (("easy", 1.0, 0.2), ("hard", 2.5, 0.6))
OFFSETS = (0.0, 1.0, 1.5, 3.0)
#: (N, d, budgets in bytes)
SHAPES = ((2000, 1024, (8_000, 16_000, 32_000)), (600, 500, (4_000, 8_000)), (210, 500, (4_000,)))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=3)
    args = parser.parse_args()
    start, rows = time.time(), []
    with limit_threads(1):
        for n_places, dim, budgets in SHAPES:
            for setting, shift, noise in SETTINGS:
                route = synthetic_route(n_places, dim, condition_shift=shift, noise=noise, seed=31)
                direction = cone_direction(route.map)
                for offset in OFFSETS:
                    X, Q = route.map + offset * direction, route.queries + offset * direction
                    cone, share = cone_ratio(normalize_rows(X)), route_share(X)
                    for budget in budgets:
                        values = {name: [key_recall(make_method(name, budget=budget, random_state=seed, **params)
                                                    .fit(X).predict(Q), "recall@2") for seed in range(args.seeds)]
                                  for name, params in (("lsh", {}), ("btel-codes", {"code": "periodic"}))}
                        centred = make_method("lsh", budget=budget).fit(X).mean_ is not None
                        effective = LSHLocalizer().effective_bits(n_places, dim, budget, cone)
                        chose = choose_method(X, None, n_places, budget)[0]["method"]
                        lsh, codes = float(np.mean(values["lsh"])), float(np.mean(values["btel-codes"]))
                        right = (chose == "lsh") == (lsh >= codes)
                        rows.append({"n_places": n_places, "n_features": dim, "setting": setting, "offset": offset,
                                     "cone_ratio": cone, "route_share": share, "budget": budget,
                                     "lsh_centred": centred, "effective_bits": effective,
                                     "bound": collision_bits(n_places), "auto_chose": chose, "auto_right": right,
                                     **values})
                        print(f"N {n_places:>4} {setting:<4} cone {cone:.2f} share {share:.2f} {budget // 1000:>2} KB  "
                              f"lsh ({'centred' if centred else 'uncentred'}) {lsh:.3f}  codes {codes:.3f}  "
                              f"effective bits / 2·log2 N {effective / collision_bits(n_places):.2f}  auto {chose}"
                              f"{'' if right else ' (the other won)'}", flush=True)
    # Maps with route share ≥ ROUTE_SHARE take auto's route branch (codes at any budget), not this condition.
    ordered = [r for r in rows if r["route_share"] < ROUTE_SHARE]
    print(f"ordered maps (route share < {ROUTE_SHARE}): the effective-bits condition chose the better of the two "
          f"in {sum(r['auto_right'] for r in ordered)} of {len(ordered)} rows; route maps (auto's route branch): "
          f"{sum(r['auto_right'] for r in rows if r not in ordered)} of {len(rows) - len(ordered)}")
    out = write_results("bench_cone_route", {"rows": rows, "seeds": args.seeds, "seconds": time.time() - start,
                                             "load": os.getloadavg()})
    print(f"wrote {out} ({time.time() - start:.0f} s)")


if __name__ == "__main__":
    main()
