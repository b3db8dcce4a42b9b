"""The ridge ρ of ``btel-codes`` on every route map of the frontier: why the rule takes ρ = 0.1.

The codes' regularisation is α = ρ × the mean non-zero eigenvalue of the centred Gram matrix
(:mod:`btel.methods.codes.solvers`). For each route map of ``btel experiment frontier`` (Gardens
Point mapped by day and at night, Nordland HOG both ways, the synthetic route) and budgets 1 KB …
256 KB, periodic codes are fitted at ρ = 0.03 (the first rule), 0.1 (the rule) and 0.3 under seeds
0 … ``--seeds`` − 1 and scored by the map's key recall (recall@2; Nordland recall@10). Each other ρ
is reported against 0.1, paired by seed. ρ is set through
:data:`btel.methods.codes.solvers.RELATIVE_ALPHA` (restored afterwards): it is a rule, not a parameter
of the estimator. One BLAS thread.

    python benchmarks/studies/codes_ridge.py      # ≈ 1 min on 2 shared cores

Writes ``benchmarks/results/bench_codes_ridge.json`` and prints the table.
"""

from __future__ import annotations

import argparse
import os
import time
from collections.abc import Iterator
from contextlib import contextmanager

import numpy as np
from _common import add_data_arguments, frontier_maps, key_recall, paired_difference, signed, write_results

import btel.methods.codes.solvers as solvers
from btel.methods import make_method
from btel.core.threads import limit_threads

BUDGETS = (1_000, 4_000, 16_000, 64_000, 256_000)
RHOS = (0.03, 0.1, 0.3)


@contextmanager
def ridge_rho(rho: float) -> Iterator[None]:
    """The codes' ρ set to ``rho`` inside the block."""
    before = solvers.RELATIVE_ALPHA
    solvers.RELATIVE_ALPHA = rho
    try:
        yield
    finally:
        solvers.RELATIVE_ALPHA = before


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=3)
    add_data_arguments(parser)
    args = parser.parse_args()
    rule = solvers.RELATIVE_ALPHA
    start, rows = time.time(), []
    with limit_threads(1):
        for base, X, Q in frontier_maps(args):
            if base["regime"] != "route":
                continue
            for budget in BUDGETS:
                values = {}
                for rho in RHOS:
                    with ridge_rho(rho):
                        models = [make_method("btel-codes", budget=budget, code="periodic", random_state=seed)
                                  for seed in range(args.seeds)]
                        values[rho] = [key_recall(model.fit(X).predict(Q), base["key"]) for model in models]
                row = {"dataset": base["dataset"], "key": base["key"], "budget": budget,
                       "values": {str(rho): v for rho, v in values.items()},
                       "versus_rule": {str(rho): paired_difference(values[rho], values[rule])
                                       for rho in RHOS if rho != rule}}
                rows.append(row)
                print(f"{base['dataset']:<24} {budget // 1000:>4} KB  "
                      + "  ".join(f"ρ {rho:g} {np.mean(v):.3f}" for rho, v in values.items())
                      + "  vs ρ = " + f"{rule:g}: "
                      + ", ".join(f"{rho} {signed(d)}" for rho, d in row["versus_rule"].items())
                      + f"  ({base['key']})", flush=True)
    out = write_results("bench_codes_ridge", {"rows": rows, "rule": rule, "seeds": args.seeds,
                                              "seconds": time.time() - start, "load": os.getloadavg()})
    print(f"wrote {out} ({time.time() - start:.0f} s)")


if __name__ == "__main__":
    main()
