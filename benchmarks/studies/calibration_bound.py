"""Calibrated auto compared on a subsample of the map against on the whole map (the cost bound).

Calibration compares its candidates on at most ``MAX_ROWS`` map places and ``MAX_VALUES`` values; a
larger map is compared on a subsample at the same bytes per row, which handicaps candidates with a
fixed cost (PQ's codebooks and projection, a whitening basis). For each Nordland direction (HOG
3780-D, 3,576 places, recall@10) at ``--budgets``, calibrated auto is fitted twice with seed 0 —
under the earlier bound (2,048 places, 2²² values: 1,109 places compared) and under the current one
(the whole map) — calibrated on the even queries and scored on the odd ones. Printed per cell:
places compared, the choice, the calibration scores of the map-only pick and of PQ, the held-out
recall and the fit seconds. One BLAS thread; the machine's load is printed.

    python benchmarks/studies/calibration_bound.py                  # ≈ 10 min on 2 shared cores

Writes ``benchmarks/results/calibration_bound.json``; the reading is on
``docs/decisions/auto-rule.md`` ("Why the bound is not lower").
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np
from _common import add_data_arguments, frontier_maps, write_results

import btel.methods.auto.calibrate as calibrate
from btel.core.storage import parse_budget
from btel.core.threads import limit_threads
from btel.methods import make_method

#: (label, MAX_ROWS, MAX_VALUES): the earlier bound and the current one.
BOUNDS = (("earlier bound (2,048 places, 2²² values)", 2048, 1 << 22),
          ("current bound", calibrate.MAX_ROWS, calibrate.MAX_VALUES))


def one_cell(X: np.ndarray, Q: np.ndarray, budget: int, max_rows: int, max_values: int) -> dict:
    """Calibrated on the even queries under one bound, scored on the odd ones."""
    calibrate.MAX_ROWS, calibrate.MAX_VALUES = max_rows, max_values
    even, odd = np.arange(0, Q.shape[0], 2), np.arange(1, Q.shape[0], 2)
    start = time.perf_counter()
    model = make_method("auto", budget=budget, calibration_tolerance=10, random_state=0)
    model.fit(X, calibration=(Q[even], even))
    seconds = time.perf_counter() - start
    table = model.choice()["calibration"]
    scores = {row["candidate"]: row.get("score") for row in table["table"]}
    held_out = float(np.mean(np.abs(model.predict(Q[odd]) - odd) <= 10))
    return {"places_compared": table["rows_compared"], "chosen": table["chosen"],
            "map_only_pick": table["map_only"], "calibration_scores": scores,
            "held_out_recall@10": held_out, "fit_s": seconds}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    add_data_arguments(parser)
    parser.add_argument("--budgets", default="1MB", help="comma-separated (default 1MB)")
    args = parser.parse_args()
    load_before = os.getloadavg()
    rows = []
    with limit_threads(1):
        for base, X, Q in frontier_maps(args):
            if not base["dataset"].startswith("nordland"):
                continue
            for budget in args.budgets.split(","):
                for label, max_rows, max_values in BOUNDS:
                    cell = one_cell(X, Q, parse_budget(budget), max_rows, max_values)
                    rows.append({"map": base["dataset"], "budget": budget, "bound": label, **cell})
                    pq = cell["calibration_scores"].get("pq")
                    print(f"{base['dataset']:24s} {budget:>6s} {label:42s} places {cell['places_compared']} "
                          f"chose {cell['chosen']:12s} pq {pq} held-out {cell['held_out_recall@10']:.3f} "
                          f"fit {cell['fit_s']:.0f} s", flush=True)
    path = write_results("calibration_bound", {"load_before": load_before, "load_after": os.getloadavg(),
                                               "rows": rows})
    print(f"load {load_before} → {os.getloadavg()}; written {path}")


if __name__ == "__main__":
    main()
