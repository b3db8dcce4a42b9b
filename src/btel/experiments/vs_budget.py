"""(c) Recall@10 vs the byte budget, 5 MB … 32 KB, at N = 3576 (summer → winter)."""

from __future__ import annotations

from pathlib import Path

from ..evaluation.plots import plot_recall_vs_storage
from ._common import ExperimentRun, NordlandData, fit_rows, full_or_quick

__all__ = ["exp_vs_budget", "plot"]


def exp_vs_budget(data: NordlandData, out: Path, quick: bool) -> ExperimentRun:
    """(c) recall@10 vs budget at full N."""
    budgets = full_or_quick(quick, ["5MB", "2MB", "1MB", "500KB", "256KB", "128KB", "64KB", "32KB"], ["50KB", "16KB"])
    methods = full_or_quick(quick, ["btel-c", "btel-r", "pq", "opq", "itq", "ryth"], ["btel-c", "pq"])
    n = 300 if quick else None
    jobs = [dict(name=name, budget=b, n_places=n) for b in budgets for name in methods]
    return ExperimentRun("vs-budget", fit_rows(data, jobs, desc="vs-budget"), out, plot=plot)


def plot(run: ExperimentRun, out: Path) -> list[Path]:
    """recall@10 against stored bytes, one line per method."""
    path = out / "recall_vs_storage.png"
    plot_recall_vs_storage([r for r in run.rows if r.ok], path, tolerance=10, title="recall@10 vs stored bytes")
    return [path]
