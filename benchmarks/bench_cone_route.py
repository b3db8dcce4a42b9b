"""Output codes against LSH on an ordered map whose rows lie in a cone, where LSH cannot afford its mean.

A synthetic 1024-D route (N = 2000; ``synthetic_route(condition_shift, noise, seed=31)``, an easy and
a hard change of conditions) gets a shared offset added to every map and query row (0, 1 and 3 ×
the mean row length), which puts the rows in a cone (cone ratio of
:func:`btel.methods.baselines.lsh.cone_ratio` 0.25 → 0.73 → 0.95). At 8 and 16 KB ``lsh`` cannot
afford its 2 KB mean (more than 1/8 of the budget) and runs uncentred; at 32 KB it centres. Both
``lsh`` and ``btel-codes`` (periodic) run under seeds 0 … ``--seeds`` − 1; recall@2. This is the
test of the mechanism behind auto's cone condition (:mod:`btel.methods.auto`, step 3).

    python benchmarks/bench_cone_route.py      # ≈ 3 min on 2 shared cores

Writes ``benchmarks/results/bench_cone_route.json`` and prints the table.
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
from btel.methods.auto import route_share
from btel.methods.baselines.lsh import cone_ratio
from btel.threads import limit_threads

SETTINGS = (("easy", 1.0, 0.2), ("hard", 2.5, 0.6))
OFFSETS = (0.0, 1.0, 3.0)
BUDGETS = (8_000, 16_000, 32_000)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=3)
    args = parser.parse_args()
    start, rows = time.time(), []
    with limit_threads(1):
        for setting, shift, noise in SETTINGS:
            route = synthetic_route(2000, 1024, condition_shift=shift, noise=noise, seed=31)
            direction = np.random.default_rng(9).normal(size=1024).astype(np.float32)
            direction *= np.linalg.norm(route.map, axis=1).mean() / np.linalg.norm(direction)
            for offset in OFFSETS:
                X, Q = route.map + offset * direction, route.queries + offset * direction
                cone, share = cone_ratio(normalize_rows(X)), route_share(X)
                for budget in BUDGETS:
                    values = {name: [key_recall(make_method(name, budget=budget, random_state=seed, **params)
                                                .fit(X).predict(Q), "recall@2") for seed in range(args.seeds)]
                              for name, params in (("lsh", {}), ("btel-codes", {"code": "periodic"}))}
                    centred = make_method("lsh", budget=budget).fit(X).mean_ is not None
                    rows.append({"setting": setting, "offset": offset, "cone_ratio": cone, "route_share": share,
                                 "budget": budget, "lsh_centred": centred, **values})
                    print(f"{setting:<4} offset {offset:.0f}  cone {cone:.2f}  share {share:.2f}  {budget // 1000:>2} KB  "
                          f"lsh ({'centred' if centred else 'uncentred'}) {np.mean(values['lsh']):.3f}  "
                          f"codes {np.mean(values['btel-codes']):.3f}  (recall@2)", flush=True)
    out = write_results("bench_cone_route", {"rows": rows, "seeds": args.seeds, "seconds": time.time() - start,
                                             "load": os.getloadavg()})
    print(f"wrote {out} ({time.time() - start:.0f} s)")


if __name__ == "__main__":
    main()
