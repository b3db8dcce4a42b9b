"""(f) The paper's sequence filter, windows a = 5 and a = 20, at N = 3576 and ≤ 1 MB (summer → winter)."""

from __future__ import annotations

from pathlib import Path

from ..evaluation.metrics import DEFAULT_TOLERANCES, recall_at_tolerance, recall_curve
from ..evaluation.plots import NORDLAND_CREDIT, plot_curves
from ..evaluation.records import EvaluationResult
from ..sequence.filter import filter_sequence
from ._common import ExperimentRun, NordlandData, fit_rows, full_or_quick

__all__ = ["exp_sequence_filter", "plot"]


def exp_sequence_filter(data: NordlandData, out: Path, quick: bool) -> ExperimentRun:
    """(f) the paper's sequence filter (a = 5, 20) on single-frame predictions at N = 3576 and 1 MB.

    The filter changes no stored bytes; it is applied to every method's predictions alike (PQ gets
    the same filter) so that the comparison stays on equal terms.
    """
    n = 300 if quick else None
    budget = "50KB" if quick else "1MB"
    methods = full_or_quick(quick, ["btel-c", "btel-r", "pq"], ["btel-r", "pq"])
    rows, curves = [], {}
    jobs = [dict(name=name, budget=budget, n_places=n) for name in methods]
    for name, result in zip(methods, fit_rows(data, jobs, desc="sequence-filter")):
        row = result.to_row()
        rows.append(EvaluationResult.from_row({**row, "window": 0}, measured=result))
        if not result.ok:
            continue
        curves[f"{name} a=0"] = result.recall_curve.tolist()
        for a in (5, 20):
            filtered = filter_sequence(result.predictions, a, n_places=row["n_places"])
            recall = recall_at_tolerance(filtered, None, DEFAULT_TOLERANCES)
            # The filter changes the point predictions only: the ranked R@K columns do not apply to it.
            plain = {k: v for k, v in row.items() if not k.startswith("R@")}
            rows.append(EvaluationResult.from_row({**plain, "method": f"{name} + filter a={a}", "window": a,
                                                   **{f"recall@{t}": v for t, v in recall.items()}}))
            curves[f"{name} a={a}"] = recall_curve(filtered, None, 80).tolist()
    return ExperimentRun("sequence-filter", rows, out, curves, plot=plot)


def plot(run: ExperimentRun, out: Path) -> list[Path]:
    """recall@t curves with and without the filter."""
    path = out / "sequence_filter.png"
    plot_curves(run.curves, path, title="Sequence filter (a = 0, 5, 20)", credit=NORDLAND_CREDIT)
    return [path]
