"""What every experiment shares: the Nordland descriptors, one fitted row, and the result files.

An experiment is a function ``(data: NordlandData, out: Path, quick: bool) -> ExperimentRun``;
:func:`write_results` turns its run into ``results.json``, ``results.csv`` and its plot(s).
"""

from __future__ import annotations

import csv
import json
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..evaluation import DEFAULT_TOLERANCES, EvaluationResult, evaluate
from ..exceptions import BudgetTooSmallError, DataNotFoundError
from ..methods import make_method
from ..storage import check_within_budget, format_bytes, parse_budget

__all__ = ["SEASONS", "QUICK_FRAMES", "NordlandData", "ExperimentRun", "default_nordland_root", "fit_row", "fit_model",
           "full_or_quick", "write_results", "describe_row"]

SEASONS = ("summer", "winter")
#: Frames per season read in quick mode.
QUICK_FRAMES = 300
#: Methods that read patch-normalised thumbnails instead of HOG.
THUMBNAIL_METHODS = {"seqslam"}


def default_nordland_root() -> Path:
    """``../shared/data/nordland64`` from the working directory (the layout CI and developers use)."""
    return Path("..") / "shared" / "data" / "nordland64"


@dataclass
class NordlandData:
    """Cached HOG and thumbnail descriptors of both Nordland seasons.

    Parameters
    ----------
    root : path
        Folder holding ``summer/`` and ``winter/`` (frame-aligned file names).
    cache_dir : path
        Where extracted descriptors are kept (``nordland64-<season>-<descriptor>.npy``).
    """

    root: Path
    cache_dir: Path
    progress: bool = True
    #: Only the first ``max_frames`` frames of each season are read (quick mode); None = all.
    max_frames: int | None = None
    #: Front-end parameters given to every method (e.g. ``{"delta": 10}``); None: each method's default.
    front_end: dict[str, Any] | None = None
    _features: dict[tuple[str, str], np.ndarray] = field(default_factory=dict, repr=False)

    def __post_init__(self) -> None:
        self.root = Path(self.root)
        self.cache_dir = Path(self.cache_dir)
        missing = [s for s in SEASONS if not (self.root / s).is_dir()]
        if missing:
            raise DataNotFoundError(
                f"Nordland folder {str(self.root)!r} lacks {', '.join(missing)}/; pass --data pointing at a "
                "folder with summer/ and winter/ frame-aligned images (e.g. ../shared/data/nordland64)."
            )

    def features(self, season: str, descriptor: str) -> np.ndarray:
        """Descriptors of every frame of ``season`` (rows in file-name order), extracted once."""
        from ..descriptors.extract import extract_cached
        from ..descriptors.images import list_images

        key = (season, descriptor)
        if key not in self._features:
            paths = list_images(self.root / season)[: self.max_frames]
            suffix = "" if self.max_frames is None else f"-first{self.max_frames}"
            out = self.cache_dir / f"nordland64-{season}-{descriptor}{suffix}.npy"
            X, _ = extract_cached(paths, out, descriptor, progress=self.progress)
            self._features[key] = X
        return self._features[key]

    def pair(self, method: str, map_season: str = "summer", n_places: int | None = None) -> tuple[np.ndarray, np.ndarray]:
        """(map, queries) for ``method``: the first ``n_places`` frames of both seasons."""
        descriptor = "patchnorm" if method in THUMBNAIL_METHODS else "hog"
        query_season = SEASONS[1 - SEASONS.index(map_season)]
        X = self.features(map_season, descriptor)
        Q = self.features(query_season, descriptor)
        n = X.shape[0] if n_places is None else min(n_places, X.shape[0])
        return X[:n], Q[:n]


@dataclass
class ExperimentRun:
    """Rows of one experiment and where they were written."""

    name: str
    rows: list[dict[str, Any]]
    out_dir: Path
    curves: dict[str, list[float]] = field(default_factory=dict)
    #: Anything else an experiment reports (the "beyond" ladder, diagnostics, protocol).
    extra: dict[str, Any] = field(default_factory=dict)


def fit_row(name: str, data: NordlandData, *, budget: Any, n_places: int | None, map_season: str = "summer",
            params: dict[str, Any] | None = None, label: str | None = None,
            extra: dict[str, Any] | None = None) -> tuple[dict[str, Any], EvaluationResult | None]:
    """Fit one method under a budget and evaluate it; a budget it cannot meet becomes a row, not an error."""
    X, Q = data.pair(name, map_season, n_places)
    kwargs = dict(params or {})
    budget_bytes = parse_budget(budget)
    if budget_bytes is not None:
        kwargs["budget"] = budget_bytes
    method = make_method(name, **{**(data.front_end or {}), **kwargs})
    front = {k: method.get_params()[k] for k in ("normalize", "whiten", "delta")}
    row: dict[str, Any] = {"method": label or name, "registry_name": name, "n_places": int(X.shape[0]),
                           "map": map_season, "budget": budget_bytes, "front_end": front,
                           "uses_query_sequence": bool(method.uses_query_sequence), **(extra or {})}
    try:
        # The paper's fixed tolerances and 0..80 curve, whatever N (the experiments compare across N).
        result = evaluate(method, X, Q, name=label or name, tolerances=DEFAULT_TOLERANCES, curve_max=80)
    except BudgetTooSmallError as exc:
        row.update(status=f"does not fit (needs ≥ {exc.minimum} B)", nbytes=None, minimum_bytes=exc.minimum)
        return row, None
    check_within_budget(label or name, result.nbytes, budget_bytes)
    row.update(status="ok", nbytes=result.nbytes, fit_s=result.fit_time_s,
               query_us=result.query_time_s_per_query * 1e6,
               **{f"recall@{t}": result.recall[t] for t in result.recall})
    if result.recall_at_k:
        row.update({f"R@{k}": v for k, v in result.recall_at_k.items()})
    return row, result


def fit_model(name: str, params: dict[str, Any], X: np.ndarray) -> tuple[Any, float] | int:
    """Fit a registered method on X: (fitted model, seconds), or the minimum bytes when its budget is too small.

    Every method is seeded (``random_state=0`` where it has one), so reruns give the same numbers.
    """
    model = make_method(name, **params)
    if "random_state" in model.get_params():
        model.set_params(random_state=0)
    start = time.perf_counter()
    try:
        model.fit(X)
    except BudgetTooSmallError as exc:
        return int(exc.minimum or 0)
    return model, time.perf_counter() - start


def full_or_quick(quick: bool, full: list[Any], small: list[Any]) -> list[Any]:
    """``small`` in quick mode, else ``full``."""
    return small if quick else full


def write_results(run: ExperimentRun, out: Path, meta: dict[str, Any]) -> None:
    """Write ``out/results.json`` (``{"run": meta, "rows", "curves", **run.extra}``), ``out/results.csv``
    (one column per key any row has, in order of first appearance) and the experiment's plot(s)."""
    out.mkdir(parents=True, exist_ok=True)
    (out / "results.json").write_text(json.dumps({"run": meta, "rows": run.rows, "curves": run.curves, **run.extra},
                                                 indent=1, default=_json_default) + "\n")
    _write_csv(out / "results.csv", run.rows)
    from ..plots import plot_experiment

    plot_experiment(run, out)


def _json_default(value: Any) -> Any:
    if isinstance(value, (np.integer,)):
        return int(value)
    if isinstance(value, (np.floating,)):
        return float(value)
    raise TypeError(f"not JSON serialisable: {type(value).__name__}")


def _write_csv(path: Path, rows: list[dict[str, Any]]) -> None:
    columns: list[str] = []
    for row in rows:
        columns.extend(k for k in row if k not in columns)
    with open(path, "w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=columns)
        writer.writeheader()
        writer.writerows(rows)


def describe_row(row: dict[str, Any]) -> str:
    """One human line for a result row (used by the CLI).

    Metric names as everywhere in btel: ``recall@t`` is the point prediction within t frames,
    ``R@K`` a correct place among the top K ranked candidates. ``†`` marks methods that use the
    query sequence; the map→query direction is named when the row has one.
    """
    name = row["method"] + (" †" if row.get("uses_query_sequence") else "")
    if row.get("direction") and "part" not in row:
        name += f" [{row['direction']}]"
    if row.get("status", "ok") != "ok":
        return f"{name:<30} {row['status']}"
    if "decoder" in row or "part" in row:  # the "beyond" experiment: say which read-out and where
        where = row.get("direction") or f"shift {row.get('condition_shift')}"
        label = f"{name} [{row.get('decoder', 'single')}, {where}]"
        ranked = f" R@10={row['R@10']:.3f}" if row.get("R@10") is not None else ""
        return (f"{label:<52} N={row['n_places']:<5} {format_bytes(row['nbytes']):>10}  "
                f"recall@10={row['recall@10']:.3f}{ranked}")
    size = format_bytes(row["nbytes"]) if row.get("nbytes") is not None else "-"
    ranked = "".join(f" R@{k}={row[f'R@{k}']:.3f}" for k in (1, 10) if row.get(f"R@{k}") is not None)
    return (f"{name:<30} N={row['n_places']:<5} {size:>10}  recall@0={row['recall@0']:.3f} "
            f"recall@10={row['recall@10']:.3f} recall@20={row['recall@20']:.3f}{ranked}")
