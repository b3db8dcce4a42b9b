"""Output codes against LSH where the route share and the route continuity disagree: how auto reads order.

auto gives an *ordered* map periodic output codes while LSH's effective bits per row are few
(:mod:`btel.methods.auto.rule`, step 3), and reads "ordered" from the route continuity
(:func:`~btel.methods.auto.route_continuity` ≥ :data:`~btel.methods.auto.ORDER_CONTINUITY`), not
from the route share (the share of rows whose nearest other row lies within 2 places), which it
once used. Two kinds of map tell the two apart:

- **Snippets.** A synthetic route (``synthetic_route(600, 500, ...)``: the size of the 600-place set of
  the frontier issue at Gardens Point's d = 500; an easy and a hard change of conditions) cut into
  snippets of L consecutive places (L = 600 is the route, 1 a map of independent places) in random
  order, map and queries alike, its rows put in a cone by a shared offset (1.5 and 3 × the mean row
  length: cone ratio ≈ 0.84 and 0.95, where ``lsh`` runs uncentred at 4 KB). Pairs and triples of
  alike rows pass the share (the issue's NetVLAD sets of independent places have 0.14–0.40) but
  carry no order beyond them. recall@0 (the exact place: the only fair tolerance once the index
  order is shuffled; recall@2 on the route itself) at 4 and 8 KB.
- **Noisy routes.** ``synthetic_route(1500, 48, ...)``: a route whose nearest row is seldom the next
  frame (share 0.05–0.07) though rows a few places apart still look alike (continuity 0.95);
  recall@2 at 2 … 16 KB.

Periodic and random output codes and LSH run under seeds 0 … ``--seeds`` − 1; auto is counted right
when it chose the better of periodic codes and LSH.

    python benchmarks/studies/auto_rule_ordered_snippets.py      # ≈ 1 min on 2 shared cores

Writes ``benchmarks/results/bench_ordered_snippets.json`` and prints the table.
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np
from _common import cone_direction, key_recall, snippet_order, write_results

from btel.datasets import synthetic_route
from btel.core.frontend import normalize_rows
from btel.methods import make_method
from btel.methods.auto import choose_method, route_continuity, route_share
from btel.methods.baselines.lsh import cone_ratio
from btel.core.threads import limit_threads

N_PLACES, DIM = 600, 500
SETTINGS = (("easy", 1.0, 0.2), ("hard", 2.5, 0.6))
OFFSETS = (1.5, 3.0)
SNIPPETS = (600, 10, 3, 2, 1)
BUDGETS = (4_000, 8_000)
NOISY_BUDGETS = (2_000, 4_000, 8_000, 16_000)
CANDIDATES = (("lsh", "lsh", {}), ("periodic codes", "btel-codes", {"code": "periodic"}),
              ("random codes", "btel-codes", {"code": "random"}))


def noisy_routes(seeds: int) -> list[dict]:
    """Routes whose nearest row is seldom the next frame: N = 1500 at d = 48 (route share 0.07–0.08,
    continuity 0.95), three changes of conditions; periodic codes, random codes and LSH by recall@2."""
    rows = []
    for setting, shift, noise in (("mild", 0.5, 0.2), *SETTINGS):
        route = synthetic_route(1500, 48, condition_shift=shift, noise=noise, seed=3)
        share, continuity = route_share(route.map), route_continuity(route.map)
        for budget in NOISY_BUDGETS:
            values = {}
            for label, name, params in CANDIDATES:
                runs = [make_method(name, budget=budget, random_state=seed, **params).fit(route.map)
                        .predict(route.queries) for seed in range(seeds)]
                values[label] = float(np.mean([key_recall(r, "recall@2") for r in runs]))
            chose = choose_method(route.map, None, 1500, budget)[0]["method"]
            right = (chose == "btel-codes") == (values["periodic codes"] > values["lsh"])
            rows.append({"setting": setting, "route_share": share, "continuity": continuity, "budget": budget,
                         "auto_chose": chose, "auto_right": right, **values})
            print(f"noisy route {setting:<4} share {share:.2f} continuity {continuity:.2f} {budget // 1000:>2} KB  "
                  f"recall@2: lsh {values['lsh']:.3f}  periodic {values['periodic codes']:.3f}  random "
                  f"{values['random codes']:.3f}  auto {chose}{'' if right else ' (the other won)'}", flush=True)
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=2)
    args = parser.parse_args()
    start, rows = time.time(), []
    with limit_threads(1):
        for setting, shift, noise in SETTINGS:
            route = synthetic_route(N_PLACES, DIM, condition_shift=shift, noise=noise, seed=31)
            direction = cone_direction(route.map)
            for offset in OFFSETS:
                for length in SNIPPETS:
                    order = snippet_order(N_PLACES, length)
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
    with limit_threads(1):
        noisy = noisy_routes(args.seeds)
    print(f"routes of noisy frames: auto chose the better in {sum(r['auto_right'] for r in noisy)} of {len(noisy)} rows")
    out = write_results("bench_ordered_snippets", {"rows": rows, "noisy_routes": noisy, "seeds": args.seeds,
                                                   "seconds": time.time() - start, "load": os.getloadavg()})
    print(f"wrote {out} ({time.time() - start:.0f} s)")


if __name__ == "__main__":
    main()
