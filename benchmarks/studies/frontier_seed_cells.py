"""The frontier's map-only verdicts again with more seeds: is auto's gap to the best row seed noise?

``btel experiment frontier`` averages every seeded row over 3 seeds (:data:`btel.experiments.frontier.SEEDS`)
and takes the best row of about twenty as the oracle, so in a cell of low recall the oracle is the
luckiest of many noisy rows. This study re-runs the frontier's rows in the cells given — the same
rows (:data:`~btel.experiments.frontier.FAST` at every budget, :data:`~btel.experiments.frontier.SLOW`
once at 64 KB), the same map-only auto, the same verdicts (:func:`btel.experiments.frontier.auto_vs_oracle`)
— with ``--seeds`` seeds for every seeded row, and prints per cell: auto, the best row, the ratio,
auto − best paired over the seeds ± its standard error, and the verdict with 3 seeds beside it
(from a finished run's ``rows.jsonl``). Every cell of the maps and budgets asked for is run, misses
or not. The calibrated row is not re-run here (``frontier_calibrated_cells.py``). One BLAS thread.

    python benchmarks/studies/frontier_seed_cells.py --rows RUN/frontier/rows.jsonl --maps gardens --seeds 20

Writes ``benchmarks/results/frontier_seed_cells.json`` (``--name`` another name) after every cell
(``"finished": false`` until the last).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

from _common import add_data_arguments, frontier_maps, write_results

from btel.core.storage import format_bytes, parse_budget
from btel.core.threads import limit_threads
from btel.experiments.frontier import (BUDGETS, FAST, SLOW, _row, auto_vs_oracle, paired_difference, row_seeds,
                                       slow_budgets)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    add_data_arguments(parser)
    parser.add_argument("--rows", type=Path, required=True, help="a finished frontier run's rows.jsonl (3 seeds)")
    parser.add_argument("--maps", default="gardens", help="maps whose name starts with this")
    parser.add_argument("--budgets", default=",".join(BUDGETS), help="comma-separated")
    parser.add_argument("--seeds", type=int, default=20, help="seeds 0 … K−1 of every seeded row")
    parser.add_argument("--name", default="frontier_seed_cells", help="results file name (no extension)")
    args = parser.parse_args()
    earlier = [json.loads(line) for line in args.rows.read_text().splitlines() if line.strip()]
    three = {(v["dataset"], v["budget"]): v for v in auto_vs_oracle(earlier) if "auto" in v}
    seeds = tuple(range(args.seeds))
    load_before, cells = os.getloadavg(), []
    with limit_threads(1):
        for base, X, Q in frontier_maps(args):
            if not base["dataset"].startswith(args.maps):
                continue
            base = {**base, "n_places": int(X.shape[0])}
            raw = X.shape[0] * X.shape[1] * 4
            for text in args.budgets.split(","):
                budget = parse_budget(text)
                if budget > raw:  # the frontier runs no budget larger than the map in float32
                    continue
                start = time.perf_counter()
                rows = []
                for label, name, params in FAST:
                    rows.append(_row(base, label, name, params, X, Q, budget, row_seeds(name, seeds)))
                if text in slow_budgets(base["dataset"], quick=False):
                    rows += [_row(base, label, name, params, X, Q, budget) for label, name, params in SLOW]
                verdict = next(v for v in auto_vs_oracle(rows) if v["budget"] == budget)
                if "auto" not in verdict:
                    continue
                auto = next(r for r in rows if r["method"] == "auto")
                best = next(r for r in rows if r["method"] == verdict["best"])
                before = three.get((base["dataset"], budget), {})
                cell = {"map": base["dataset"], "budget": text, "seeds": len(seeds), "auto": verdict["auto"],
                        "auto_chose": verdict["auto_chose"], "best": verdict["best"], "best_value": verdict["best_value"],
                        "ratio": verdict["ratio"], "meets_0.95": verdict["meets_0.95"],
                        "auto_minus_best": paired_difference(auto, best),
                        "three_seeds": {k: before.get(k) for k in ("auto", "best", "best_value", "ratio", "meets_0.95")},
                        "rows": {r["method"]: r.get("value") for r in rows if r.get("status") == "ok"},
                        "seconds": time.perf_counter() - start}
                cells.append(cell)
                d = cell["auto_minus_best"]
                se = "" if d["diff_se"] is None else f" ± {d['diff_se']:.3f}"
                print(f"{cell['map']:32s} {format_bytes(budget):>8s}  auto {cell['auto']:.3f} ({cell['auto_chose']})  "
                      f"best {cell['best']} {cell['best_value']:.3f}  ratio {cell['ratio']:.2f} "
                      f"{'meets' if cell['meets_0.95'] else 'MISS '}  auto − best {d['diff']:+.3f}{se}  | 3 seeds: "
                      f"ratio {before.get('ratio', float('nan')):.2f} ({before.get('best')})  {cell['seconds']:.0f} s",
                      flush=True)
                write_results(args.name, {"rows_file": str(args.rows), "load_before": load_before, "cells": cells,
                                          "command": " ".join(["python", *sys.argv]), "finished": False})
    met = sum(c["meets_0.95"] for c in cells)
    print(f"{len(seeds)} seeds: auto ≥ 0.95 × best in {met} of {len(cells)} cells; with 3 seeds "
          f"{sum(bool(c['three_seeds']['meets_0.95']) for c in cells)} of {len(cells)}")
    path = write_results(args.name, {"rows_file": str(args.rows), "load_before": load_before,
                                     "load_after": os.getloadavg(), "cells": cells,
                                     "command": " ".join(["python", *sys.argv]), "finished": True})
    print(f"load {load_before} → {os.getloadavg()}; written {path}")


if __name__ == "__main__":
    main()
