"""(b) Recall@10 vs the number of places N = 64 … 3576 at ≤ 0.5 MB (summer → winter)."""

from __future__ import annotations

from pathlib import Path

from ..evaluation.plots import plot_recall_vs_n
from ._common import ExperimentRun, NordlandData, fit_rows, full_or_quick

__all__ = ["exp_vs_n", "plot"]


def exp_vs_n(data: NordlandData, out: Path, quick: bool) -> ExperimentRun:
    """(b) recall@10 vs N at ≤ 0.5 MB."""
    sizes = full_or_quick(quick, [64, 128, 256, 512, 1024, 2048, 3576], [64, 256])
    methods = full_or_quick(quick, ["btel-c", "btel-r", "pq", "opq", "ryth"], ["btel-c", "pq"])
    budget = "50KB" if quick else "500KB"
    jobs = [dict(name=name, budget=budget, n_places=n) for n in sizes for name in methods]
    return ExperimentRun("vs-n", fit_rows(data, jobs, desc="vs-n"), out, plot=plot)


def plot(run: ExperimentRun, out: Path) -> list[Path]:
    """recall@10 against the number of map places, one line per method."""
    path = out / "recall_vs_n.png"
    plot_recall_vs_n([r for r in run.rows if r.ok], path, tolerance=10, title="recall@10 vs N")
    return [path]
