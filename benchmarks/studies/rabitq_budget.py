"""RaBitQ against the cheap baselines at 4 KB … 128 KB: one table per map, same run, same harness.

Rows (registry name, parameters), each fitted under every budget and scored by
:func:`btel.evaluation.evaluate` (recall@0 = R@1 exact place, recall@2, recall@10):

- ``rabitq`` (D and B by its documented budget rule; nothing tuned here),
- ``rabitq`` with ``whiten="shrink"`` (the same rule on shrinkage-whitened rows),
- ``lsh`` (asymmetric scoring, its default), ``lsh`` with ``whiten="shrink"``, ``pq``,
- ``bruteforce`` with ``whiten="shrink"`` and plain cosine ``bruteforce``: unbudgeted references.

Maps (query j is place j in every one):

- Gardens Point day→night, NetVLAD 500-D, N = 200 (``../shared/data/gardenspoint_netvlad``): a route;
- Nordland summer→winter, HOG 3780-D, N = 3576 (``../shared/data/nordland64``, extracted once into
  ``--cache``): a route;
- synthetic independent places: ``synthetic_route(1000, 256, condition_shift=1.0, seed=11)``, map and
  queries permuted alike (as ``btel experiment frontier``): no route structure.

A budget a method cannot meet is a "does not fit" cell (its BudgetTooSmallError), never an abort.
One BLAS and one faiss thread throughout (the machine is shared).

    python benchmarks/studies/rabitq_budget.py            # ≈ 10 min on 2 shared cores
    python benchmarks/studies/rabitq_budget.py --quick    # Gardens Point and the synthetic map only

Writes ``benchmarks/results/bench_rabitq.json`` (every cell) and prints the tables.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path
from typing import Any

import numpy as np

from btel.evaluation.measure import evaluate
from btel.exceptions import BudgetTooSmallError
from btel.methods import make_method
from btel.core.storage import parse_budget
from btel.core.threads import limit_threads

HERE = Path(__file__).resolve().parents[1]  # benchmarks/
BUDGETS = ("4KB", "8KB", "16KB", "32KB", "64KB", "128KB")
BUDGETED = (("rabitq", "rabitq", {}), ("rabitq shrink", "rabitq", {"whiten": "shrink"}), ("lsh", "lsh", {}),
            ("lsh shrink", "lsh", {"whiten": "shrink"}),
            ("pq", "pq", {}))
REFERENCES = (("bruteforce shrink", "bruteforce", {"whiten": "shrink"}), ("bruteforce", "bruteforce", {}))


def maps(shared: Path, cache: Path, quick: bool) -> list[tuple[str, np.ndarray, np.ndarray]]:
    from btel.datasets import synthetic_route

    out = []
    with np.load(shared / "gardenspoint_netvlad" / "hiddenRepr-GardensPoint.npz", allow_pickle=False) as z:
        out.append(("gardens-point", z["hlrTrain"].astype(np.float32), z["hlrTest"].astype(np.float32)))
    if not quick:
        from btel.experiments._common import NordlandData

        data = NordlandData(shared / "nordland64", cache, progress=False)
        X, Q = data.features("summer", "hog"), data.features("winter", "hog")
        n = min(len(X), len(Q))
        out.append(("nordland summer→winter", X[:n], Q[:n]))
    other = synthetic_route(1000, 256, condition_shift=1.0, seed=11)
    perm = np.random.default_rng(1).permutation(1000)
    out.append(("synthetic independent", other.map[perm], other.queries[perm]))
    return out


def cell(name: str, params: dict[str, Any], X: np.ndarray, Q: np.ndarray,
         budget: int | None) -> dict[str, Any]:
    model = make_method(name, **({"budget": budget} if budget else {}), **params)
    start = time.perf_counter()
    try:
        result = evaluate(model, X, Q, tolerances=(0, 2, 10), ks=(), budget=budget, timing_repeats=1)
    except BudgetTooSmallError as exc:
        return {"status": "does not fit", "minimum": exc.minimum}
    row = {"status": "ok", "nbytes": int(model.nbytes),
           **{f"recall@{t}": float(v) for t, v in result.recall.items()},
           "fit_s": result.fit_time_s, "wall_s": time.perf_counter() - start}
    if name == "rabitq":
        row["dim"], row["nbits"] = int(model.dim_), int(model.nbits_)
    return row


def table(rows: list[dict[str, Any]], dataset: str, key: str) -> str:
    labels = [label for label, _, _ in BUDGETED + REFERENCES]
    lines = [f"{dataset}: {key}", "| method | " + " | ".join(BUDGETS) + " |",
             "|---" * (len(BUDGETS) + 1) + "|"]
    for label in labels:
        cells = []
        for b in BUDGETS:
            r = next((r for r in rows if r["dataset"] == dataset and r["method"] == label
                      and r["budget"] in (parse_budget(b), None)), None)
            cells.append("—" if r is None or r["status"] != "ok" else f"{r[key]:.3f}")
        lines.append(f"| {label} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--shared", type=Path, default=HERE.parent.parent / "shared" / "data")
    parser.add_argument("--cache", type=Path, default=HERE / "results" / "cache")
    parser.add_argument("--out", type=Path, default=HERE / "results" / "bench_rabitq.json")
    args = parser.parse_args()
    rows: list[dict[str, Any]] = []
    started = time.perf_counter()
    with limit_threads(1):
        for dataset, X, Q in maps(args.shared, args.cache, args.quick):
            for label, name, params in BUDGETED:
                for b in BUDGETS:
                    budget = parse_budget(b)
                    rows.append({"dataset": dataset, "n_places": int(X.shape[0]), "d": int(X.shape[1]),
                                 "method": label, "registry_name": name, "options": params, "budget": budget,
                                 **cell(name, params, X, Q, budget)})
                    print(json.dumps(rows[-1], ensure_ascii=False), flush=True)
            for label, name, params in REFERENCES:
                rows.append({"dataset": dataset, "n_places": int(X.shape[0]), "d": int(X.shape[1]),
                             "method": label, "registry_name": name, "options": params, "budget": None,
                             **cell(name, params, X, Q, None)})
                print(json.dumps(rows[-1], ensure_ascii=False), flush=True)
            args.out.write_text(json.dumps({"rows": rows, "budgets": BUDGETS}, indent=1, ensure_ascii=False))
    summary = {"rows": rows, "budgets": BUDGETS, "wall_s": time.perf_counter() - started}
    args.out.write_text(json.dumps(summary, indent=1, ensure_ascii=False))
    for dataset in dict.fromkeys(r["dataset"] for r in rows):
        keys = ("recall@0", "recall@2") if dataset == "gardens-point" else \
            ("recall@0", "recall@10") if dataset.startswith("nordland") else ("recall@0",)
        for key in keys:
            print("\n" + table(rows, dataset, key))


if __name__ == "__main__":
    main()
