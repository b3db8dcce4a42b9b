"""The paper's experiments on real Nordland frames, under one storage budget for every method (SPEC §9).

Data: ``nordland64/{summer,winter}`` (3576 frame-aligned 64×32 frames, every 10th frame of the
videos). Descriptors: HOG (3780-D, SPEC §10) for every method except SeqSLAM, which works on its
own front end, 64×32 patch-normalised thumbnails (2048-D); both are extracted once and cached.
Ground truth is frame-aligned; tolerance is in frames (one frame ≈ 200 m here).

=================== ===================================================================================
name                what
=================== ===================================================================================
``accuracy``        (a) recall vs tolerance t = 0…80 at ≤ 2 MB, N = 2000, summer→winter and winter→summer
``vs-n``            (b) recall@10 vs N = 64 … 3576 at ≤ 0.5 MB
``vs-budget``       (c) recall@10 vs budget 5 MB … 32 KB at N = 3576
``feature-ratio``   (d) BTE-C with c = 0.1 … 1 at r = 1
``regions``         (e) BTEL with r = 1 … 20 at c = 0.1
``sequence-filter`` (f) the sequence filter, a = 5 and a = 20, at N = 3576 and 1 MB
=================== ===================================================================================

Every row carries the method's bytes. A method that cannot fit a budget is reported as such (with
its minimum), never run over it; a fitted method whose bytes exceed its budget fails the run
(:class:`~btel.exceptions.BudgetExceededError`). Brute force is the unbudgeted upper reference.
``quick=True`` shrinks every experiment (first 300 frames, few points) for the tests.
"""

from __future__ import annotations

import csv
import json
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import numpy as np

from .evaluation import DEFAULT_TOLERANCES, EvaluationResult, evaluate, recall_at_tolerance, recall_curve, run_metadata
from .exceptions import BudgetTooSmallError, DataNotFoundError, InvalidParameterError
from .methods import make_method
from .sequence import filter_sequence
from .storage import check_within_budget, format_bytes, parse_budget

__all__ = ["EXPERIMENTS", "NordlandData", "ExperimentRun", "run_experiment", "default_nordland_root"]

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
        from .descriptors.extract import extract_cached
        from .descriptors.images import list_images

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


def _fit_row(name: str, data: NordlandData, *, budget: Any, n_places: int | None, map_season: str = "summer",
             params: dict[str, Any] | None = None, label: str | None = None,
             extra: dict[str, Any] | None = None) -> tuple[dict[str, Any], EvaluationResult | None]:
    """Fit one method under a budget and evaluate it; a budget it cannot meet becomes a row, not an error."""
    X, Q = data.pair(name, map_season, n_places)
    kwargs = dict(params or {})
    budget_bytes = parse_budget(budget)
    if budget_bytes is not None:
        kwargs["budget"] = budget_bytes
    row: dict[str, Any] = {"method": label or name, "registry_name": name, "n_places": int(X.shape[0]),
                           "map": map_season, "budget": budget_bytes, **(extra or {})}
    method = make_method(name, **kwargs)
    try:
        result = evaluate(method, X, Q, name=label or name)
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


def _sizes(quick: bool, full: list[Any], small: list[Any]) -> list[Any]:
    return small if quick else full


def exp_accuracy(data: NordlandData, out: Path, quick: bool) -> ExperimentRun:
    """(a) recall vs tolerance at ≤ 2 MB, N = 2000, both directions, all methods."""
    n = 300 if quick else 2000
    budget = "50KB" if quick else "2MB"
    methods = _sizes(quick, ["btel-c", "btel-f", "btel-r", "pq", "opq", "itq", "ryth", "seqslam", "bruteforce"],
                     ["btel-c", "btel-r", "pq", "bruteforce"])
    rows, curves = [], {}
    for map_season in SEASONS:
        for name in methods:
            row, result = _fit_row(name, data, budget=None if name == "bruteforce" else budget, n_places=n,
                                   map_season=map_season)
            row["direction"] = f"{map_season}→{SEASONS[1 - SEASONS.index(map_season)]}"
            rows.append(row)
            if result is not None:
                curves[f"{name} {row['direction']}"] = result.recall_curve.tolist()
    return ExperimentRun("accuracy", rows, out, curves)


def exp_vs_n(data: NordlandData, out: Path, quick: bool) -> ExperimentRun:
    """(b) recall@10 vs N at ≤ 0.5 MB."""
    sizes = _sizes(quick, [64, 128, 256, 512, 1024, 2048, 3576], [64, 256])
    methods = _sizes(quick, ["btel-c", "btel-r", "pq", "opq", "ryth"], ["btel-c", "pq"])
    budget = "50KB" if quick else "500KB"
    rows = [_fit_row(name, data, budget=budget, n_places=n)[0] for n in sizes for name in methods]
    return ExperimentRun("vs-n", rows, out)


def exp_vs_budget(data: NordlandData, out: Path, quick: bool) -> ExperimentRun:
    """(c) recall@10 vs budget at full N."""
    budgets = _sizes(quick, ["5MB", "2MB", "1MB", "500KB", "256KB", "128KB", "64KB", "32KB"], ["50KB", "16KB"])
    methods = _sizes(quick, ["btel-c", "btel-r", "pq", "opq", "itq", "ryth"], ["btel-c", "pq"])
    n = 300 if quick else None
    rows = [_fit_row(name, data, budget=b, n_places=n)[0] for b in budgets for name in methods]
    return ExperimentRun("vs-budget", rows, out)


def exp_feature_ratio(data: NordlandData, out: Path, quick: bool) -> ExperimentRun:
    """(d) BTE-C with c = 0.1 … 1 at r = 1 (no budget; bytes reported)."""
    ratios = _sizes(quick, [0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9, 1.0], [0.1, 0.3])
    n = 300 if quick else None
    rows = [_fit_row("btel-c", data, budget=None, n_places=n, params={"feature_ratio": c},
                     label=f"BTE-C c={c:g}", extra={"feature_ratio": c})[0] for c in ratios]
    return ExperimentRun("feature-ratio", rows, out)


def exp_regions(data: NordlandData, out: Path, quick: bool) -> ExperimentRun:
    """(e) BTEL with r = 1 … 20 at c = 0.1 (no budget; bytes reported)."""
    counts = _sizes(quick, [1, 2, 5, 10, 15, 20], [1, 4])
    n = 300 if quick else None
    rows = [_fit_row("btel-c", data, budget=None, n_places=n, params={"feature_ratio": 0.1, "n_regions": r},
                     label=f"BTEL r={r}", extra={"n_regions": r})[0] for r in counts]
    return ExperimentRun("regions", rows, out)


def exp_sequence_filter(data: NordlandData, out: Path, quick: bool) -> ExperimentRun:
    """(f) the paper's sequence filter (a = 5, 20) on single-frame predictions at N = 3576 and 1 MB.

    The filter changes no stored bytes; it is applied to every method's predictions alike (PQ gets
    the same filter) so that the comparison stays on equal terms.
    """
    n = 300 if quick else None
    budget = "50KB" if quick else "1MB"
    methods = _sizes(quick, ["btel-c", "btel-r", "pq"], ["btel-r", "pq"])
    rows, curves = [], {}
    for name in methods:
        row, result = _fit_row(name, data, budget=budget, n_places=n)
        rows.append({**row, "window": 0})
        if result is None:
            continue
        curves[f"{name} a=0"] = result.recall_curve.tolist()
        for a in (5, 20):
            filtered = filter_sequence(result.predictions, a, n_places=row["n_places"])
            recall = recall_at_tolerance(filtered, None, DEFAULT_TOLERANCES)
            rows.append({**row, "method": f"{name} + filter a={a}", "window": a,
                         **{f"recall@{t}": v for t, v in recall.items()}})
            curves[f"{name} a={a}"] = recall_curve(filtered, None, 80).tolist()
    return ExperimentRun("sequence-filter", rows, out, curves)


from .beyond import exp_beyond  # noqa: E402  (it imports this module's helpers lazily)

EXPERIMENTS: dict[str, Callable[[NordlandData, Path, bool], ExperimentRun]] = {
    "accuracy": exp_accuracy,
    "vs-n": exp_vs_n,
    "vs-budget": exp_vs_budget,
    "feature-ratio": exp_feature_ratio,
    "regions": exp_regions,
    "sequence-filter": exp_sequence_filter,
    "beyond": exp_beyond,
}


def run_experiment(name: str, *, data_root: str | Path | None = None, out_dir: str | Path = "runs/experiments",
                   cache_dir: str | Path | None = None, quick: bool = False, progress: bool = True,
                   command: str | None = None) -> ExperimentRun:
    """Run one experiment and write ``<out_dir>/<name>/results.{csv,json}`` and its plot(s).

    Raises
    ------
    InvalidParameterError
        Unknown experiment name.
    DataNotFoundError
        Missing Nordland folders.
    BudgetExceededError
        A method stored more bytes than its budget.
    """
    if name not in EXPERIMENTS:
        raise InvalidParameterError(f"unknown experiment {name!r}; choose from {', '.join(EXPERIMENTS)} or 'all'.")
    root = Path(data_root) if data_root else default_nordland_root()
    out = Path(out_dir) / name
    data = NordlandData(root, Path(cache_dir) if cache_dir else Path(out_dir) / "cache", progress=progress,
                        max_frames=QUICK_FRAMES if quick else None)
    start = time.perf_counter()
    run = EXPERIMENTS[name](data, out, quick)
    out.mkdir(parents=True, exist_ok=True)
    meta = {**run_metadata(command or f"btel experiment {name}{' --quick' if quick else ''}"), "experiment": name, "quick": quick, "data": str(root.resolve()),
            "descriptor": "HOG 3780-D (SeqSLAM: 64×32 patch-normalised, 2048-D)",
            "seconds": time.perf_counter() - start}
    (out / "results.json").write_text(json.dumps({"run": meta, "rows": run.rows, "curves": run.curves, **run.extra},
                                                 indent=1, default=_json_default) + "\n")
    _write_csv(out / "results.csv", run.rows)
    from .plots import plot_experiment

    plot_experiment(run, out)
    return run


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
    """One human line for a result row (used by the CLI)."""
    if row.get("status", "ok") != "ok":
        return f"{row['method']:<26} {row['status']}"
    if "decoder" in row or "part" in row:  # the "beyond" experiment: say which read-out and where
        where = row.get("direction") or f"shift {row.get('condition_shift')}"
        label = f"{row['method']} [{row.get('decoder', 'single')}, {where}]"
        ranked = f" R@10(ranked)={row['R@10']:.3f}" if row.get("R@10") is not None else ""
        return (f"{label:<52} N={row['n_places']:<5} {format_bytes(row['nbytes']):>10}  "
                f"R@10={row['recall@10']:.3f}{ranked}")
    size = format_bytes(row["nbytes"]) if row.get("nbytes") is not None else "-"
    return (f"{row['method']:<26} N={row['n_places']:<5} {size:>10}  R@0={row['recall@0']:.3f} "
            f"R@10={row['recall@10']:.3f} R@20={row['recall@20']:.3f}")
