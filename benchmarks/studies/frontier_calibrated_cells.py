"""Re-measure the frontier's calibrated-auto row in chosen cells, against a finished frontier run.

``btel experiment frontier`` takes hours with its calibrated row; after a change to calibration,
this recomputes that row (:func:`btel.experiments.frontier._calibrated_row`: cross-fitted on the
even / odd query halves) in the cells given, at the seeds given, and sets it against the oracle and
map-only auto of an existing run's ``rows.jsonl``. One BLAS thread.

    python benchmarks/studies/frontier_calibrated_cells.py --rows RUN/frontier/rows.jsonl \\
        --maps nordland --budgets 1MB --seeds 0          # ≈ 7 min on 2 cores

``--oracle SEED_CELLS.json`` (from ``frontier_seed_cells.py``) takes each cell's best row and
map-only auto from that study instead, so a calibrated row at 20 seeds is set against the 20-seed
oracle.

Writes ``benchmarks/results/frontier_calibrated_cells.json`` (``--name`` another name) after every cell
and prints one line per cell.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

from _common import add_data_arguments, frontier_maps, write_results

from btel.core.storage import parse_budget
from btel.core.threads import limit_threads
from btel.experiments.frontier import _calibrated_row


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    add_data_arguments(parser)
    parser.add_argument("--rows", type=Path, required=True, help="a finished frontier run's rows.jsonl")
    parser.add_argument("--maps", default="nordland", help="maps whose name starts with this")
    parser.add_argument("--budgets", default="1MB", help="comma-separated")
    parser.add_argument("--seeds", default="0", help="comma-separated random_state values")
    parser.add_argument("--name", default="frontier_calibrated_cells", help="results file name (no extension)")
    parser.add_argument("--oracle", type=Path, action="append", default=[],
                        help="frontier_seed_cells.py results (repeatable): take each cell's best row and map-only "
                             "auto from there (its seeds) instead of from --rows")
    args = parser.parse_args()
    rows = [json.loads(line) for line in args.rows.read_text().splitlines() if line.strip()]
    oracle = {(c["map"], parse_budget(c["budget"])): c for path in args.oracle
              for c in json.loads(path.read_text())["cells"]}
    seeds = tuple(int(s) for s in args.seeds.split(","))
    load_before, out = os.getloadavg(), []
    with limit_threads(1):
        for base, X, Q in frontier_maps(args):
            if not base["dataset"].startswith(args.maps):
                continue
            for text in args.budgets.split(","):
                budget = parse_budget(text)
                start = time.perf_counter()
                row = _calibrated_row({**base, "n_places": int(X.shape[0])}, X, Q, budget, seeds)
                here = [r for r in rows if r["dataset"] == base["dataset"] and r.get("budget") == budget
                        and r.get("status") == "ok"]
                best = max((r for r in here if r["registry_name"] != "auto"), key=lambda r: r["value"])
                auto = next(r for r in here if r["method"] == "auto")
                map_only = [v for s, v in zip(auto["seeds"], auto["seed_values"]) if s in seeds]
                seeded = oracle.get((base["dataset"], budget))
                if seeded is not None:  # the best row and map-only auto over that study's seeds
                    best = {"method": seeded["best"], "value": seeded["best_value"]}
                    map_only = [seeded["auto"]]
                cell = {"map": base["dataset"], "budget": text, "seeds": list(seeds), "calibrated": row["value"],
                        "half_values": row["half_values"],
                        "choices": {h: [c["chose"] for c in cs] for h, cs in row["calibrated_choices"].items()},
                        "best": best["method"], "best_value": best["value"], "ratio": row["value"] / best["value"],
                        "oracle": "seed cells" if seeded is not None else "rows",
                        "oracle_seeds": seeded["seeds"] if seeded is not None else len(auto["seeds"]),
                        "map_only_auto_same_seeds": map_only,
                        "seconds": time.perf_counter() - start}
                out.append(cell)
                print(f"{cell['map']:24s} {text:>6s} calibrated {cell['calibrated']:.3f} ({cell['ratio']:.3f} × "
                      f"{cell['best']} {cell['best_value']:.3f}); map-only auto {cell['map_only_auto_same_seeds']}; "
                      f"chose {cell['choices']}; {cell['seconds']:.0f} s", flush=True)
                write_results(args.name, {"rows_file": str(args.rows), "load_before": load_before, "cells": out,
                                          "finished": False})
    path = write_results(args.name, {"rows_file": str(args.rows), "load_before": load_before,
                                     "load_after": os.getloadavg(), "cells": out, "finished": True,
                                     "command": " ".join(["python", *sys.argv])})
    print(f"load {load_before} → {os.getloadavg()}; written {path}")


if __name__ == "__main__":
    main()
