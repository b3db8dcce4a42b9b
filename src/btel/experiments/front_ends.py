"""Front ends: how much normalisation, delta descriptors and whitening move each method (beyond the paper).

What happens to a descriptor before a method sees it (:mod:`btel.core.frontend`) is an option of every
method, so the same methods are fitted under each front end at the same budgets:

- front ends: ``none`` (raw rows), ``l2`` (the default), ``power`` (signed square root + L2),
  ``l2 + delta w`` (delta descriptors, Garg & Milford 2020; w = 10 and 20 frames on Nordland, 5 on
  Gardens Point), ``l2 + whiten p`` (PCA whitening to p dimensions, its matrix counted in the bytes);
- methods: brute force (the unbudgeted reference), PQ and ITQ at ≤ 500 KB and PQ, BTE-C and
  btel-codes at ≤ 64 KB on Nordland HOG (N = 3576, both directions); brute force, PQ, OPQ, ITQ, BTE-C,
  BTE-C with offset codes and btel-codes at ≤ 32 KB on Gardens Point NetVLAD day → night (N = 200);
- read-outs: single frame (recall@t and R@K, best first) and the HMM over places
  (:meth:`~btel.methods.base.PlaceLocalizer.predict_sequence`, default options, no extra bytes). Nothing is
  tuned on the reported queries: the front-end settings and HMM options are fixed in advance.

A delta front end makes a method use the query sequence (``uses_query_sequence``); such rows are
marked ``sequence`` in the ``uses`` column, as are all HMM rows, so they are not mistaken for
single-frame results.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from ..evaluation.metrics import DEFAULT_TOLERANCES, recall_at_k, recall_at_tolerance
from ..exceptions import BudgetTooSmallError
from ..evaluation.plots import NORDLAND_CREDIT, plot_method_bars
from ..core.storage import check_within_budget, format_bytes, parse_budget
from ..datasets.sources import gardens_point_path, load_gardens_point_netvlad
from ..evaluation.records import does_not_fit_status
from ._common import SEASONS, ExperimentRun, NordlandData, fit_model

__all__ = ["exp_front_ends", "plot", "FRONT_ENDS"]

#: Front end label → parameters (Nordland windows; Gardens Point uses its own delta window).
FRONT_ENDS: dict[str, dict[str, Any]] = {
    "none": {"normalize": "none"},
    "l2": {"normalize": "l2"},
    "power": {"normalize": "power"},
    "l2 + delta 10": {"normalize": "l2", "delta": 10},
    "l2 + delta 20": {"normalize": "l2", "delta": 20},
    "l2 + whiten 256": {"normalize": "l2", "whiten": 256},
}
GARDENS_POINT_FRONT_ENDS: dict[str, dict[str, Any]] = {
    "none": {"normalize": "none"},
    "l2": {"normalize": "l2"},
    "power": {"normalize": "power"},
    "l2 + delta 5": {"normalize": "l2", "delta": 5},
    "l2 + whiten 64": {"normalize": "l2", "whiten": 64},
}
TOLERANCES = DEFAULT_TOLERANCES


def _rows_for(data: NordlandData, label: str, name: str, params: dict[str, Any], budget: Any, X: np.ndarray,
              Q: np.ndarray, base: dict[str, Any], tolerance_k: int, hmm: bool = True) -> list[dict[str, Any]]:
    """Single-frame and HMM rows of one method under one front end (or its 'does not fit' row)."""
    budget_bytes = parse_budget(budget)
    truth = np.arange(len(Q))
    row = {**base, "method": label, "registry_name": name, "front_end": params, "budget": budget_bytes,
           "n_places": int(len(X))}
    try:
        model, fit_s, _ = fit_model(name, {**params, **({"budget": budget_bytes} if budget_bytes else {})}, X, data)
    except BudgetTooSmallError as exc:
        return [{**row, "decoder": "single", "status": does_not_fit_status(exc.minimum), "nbytes": None,
                 "minimum_bytes": exc.minimum}]
    check_within_budget(label, model.nbytes, budget_bytes)
    common = {**row, "status": "ok", "nbytes": int(model.nbytes), "fit_s": fit_s}
    ranked = model.rank(Q, 10)
    single = ranked[:, 0]
    uses = "sequence" if model.uses_query_sequence else "single frame"
    out = [{**common, "decoder": "single", "uses": uses,
            **{f"recall@{t}": v for t, v in recall_at_tolerance(single, truth, TOLERANCES).items()},
            **{f"R@{k}": v for k, v in recall_at_k(ranked, truth, (1, 5, 10), tolerance=tolerance_k).items()}}]
    if hmm:
        decoded = model.predict_sequence(Q, "hmm")
        out.append({**common, "decoder": "HMM", "uses": "sequence",
                    **{f"recall@{t}": v for t, v in recall_at_tolerance(decoded, truth, TOLERANCES).items()}})
    return out


def _nordland(data: NordlandData, quick: bool, log: Any) -> list[dict[str, Any]]:
    methods = [("brute force", "bruteforce", None), ("PQ", "pq", "500KB"), ("ITQ", "itq", "500KB"),
               ("PQ", "pq", "64KB"), ("BTE-C", "btel-c", "64KB"), ("btel-codes", "btel-codes", "64KB")]
    fronts = FRONT_ENDS if not quick else {k: FRONT_ENDS[k] for k in ("none", "l2", "l2 + delta 10")}
    if quick:
        methods = [("brute force", "bruteforce", None), ("PQ", "pq", "50KB"), ("BTE-C", "btel-c", "16KB")]
    rows = []
    for map_season in SEASONS[:1] if quick else SEASONS:
        query_season = SEASONS[1 - SEASONS.index(map_season)]
        direction = f"{map_season}→{query_season}"
        X, Q = data.features(map_season, "hog"), data.features(query_season, "hog")
        n = min(len(X), len(Q))
        for front, params in fronts.items():
            for label, name, budget in methods:
                if name in ("btel-c", "btel-codes") and front in ("power", "l2 + whiten 256", "l2 + delta 10"):
                    continue  # near chance on this pair whatever the front end: three fits each are enough
                base = {"part": "nordland", "descriptor": "HOG", "direction": direction, "front": front}
                rows += _rows_for(data, label, name, params, budget, X[:n], Q[:n], base, tolerance_k=10)
            log(f"{direction} front end {front} done")
    return rows


def _gardens_point(data: NordlandData, quick: bool, log: Any) -> list[dict[str, Any]]:
    path = gardens_point_path(data.root.parent)
    if not path.is_file():
        return [{"part": "gardens-point", "method": "-", "status": f"skipped: {path} not found", "n_places": 0}]
    X, Q = load_gardens_point_netvlad(path)
    methods = [("brute force", "bruteforce", None, {}), ("PQ", "pq", "32KB", {}), ("OPQ", "opq", "32KB", {}),
               ("ITQ", "itq", "32KB", {}), ("BTE-C", "btel-c", "32KB", {}),
               ("BTE-C offset codes m=2", "btel-c", "32KB", {"code_copies": 2}),
               ("btel-codes", "btel-codes", "32KB", {})]
    rows = []
    for front, params in GARDENS_POINT_FRONT_ENDS.items():
        if quick and front not in ("none", "l2"):
            continue
        for label, name, budget, opts in methods[:3] if quick else methods:
            base = {"part": "gardens-point", "descriptor": "NetVLAD 500-D", "direction": "day→night", "front": front}
            rows += _rows_for(data, label, name, {**params, **opts}, budget, X, Q, base, tolerance_k=2)
        log(f"Gardens Point front end {front} done")
    return rows


def exp_front_ends(data: NordlandData, out: Path, quick: bool) -> ExperimentRun:
    """Every front end × method × read-out on Nordland HOG and Gardens Point NetVLAD (module docstring)."""
    log = (lambda msg: print(f"  {msg}", flush=True)) if data.progress else (lambda msg: None)
    rows = _nordland(data, quick, log) + _gardens_point(data, quick, log)
    run = ExperimentRun.from_rows("front-ends", rows, out, plot=plot)
    run.extra = {"front_ends": FRONT_ENDS, "gardens_point_front_ends": GARDENS_POINT_FRONT_ENDS,
                 "protocol": "front-end settings and HMM options fixed in advance; nothing tuned on the queries"}
    return run


def plot(run: ExperimentRun, out_dir: Path) -> list[Path]:
    """The "front-ends" experiment: one bar group per method (and budget), one bar per front end."""
    written = []
    for part, direction in dict.fromkeys((r.labels.get("part"), r.labels.get("direction")) for r in run.rows
                                         if r.labels.get("direction")):
        single = [replace(r, name=f"{r.name} ({format_bytes(r.budget) if r.budget else 'no budget'})")
                  for r in run.rows if r.labels.get("part") == part and r.labels.get("direction") == direction
                  and r.labels.get("decoder") == "single"]
        if not any(r.ok for r in single):
            continue
        t = 10 if part == "nordland" else 2
        path = out_dir / f"{part}_{direction.replace('→', '_to_')}.png"
        what = "Nordland HOG" if part == "nordland" else "Gardens Point NetVLAD"
        plot_method_bars(single, path, group_key="front", value_key=f"recall@{t}",
                         title=f"{what} {direction}: single-frame recall@{t} by front end",
                         credit=NORDLAND_CREDIT if part == "nordland" else None)
        written.append(path)
    return written
