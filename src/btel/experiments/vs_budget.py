"""(c) Recall@10 vs the byte budget, 5 MB … 32 KB, at N = 3576 (summer → winter)."""

from __future__ import annotations

from pathlib import Path

from ._common import ExperimentRun, NordlandData, fit_rows, full_or_quick

__all__ = ["exp_vs_budget"]


def exp_vs_budget(data: NordlandData, out: Path, quick: bool) -> ExperimentRun:
    """(c) recall@10 vs budget at full N."""
    budgets = full_or_quick(quick, ["5MB", "2MB", "1MB", "500KB", "256KB", "128KB", "64KB", "32KB"], ["50KB", "16KB"])
    methods = full_or_quick(quick, ["btel-c", "btel-r", "pq", "opq", "itq", "ryth"], ["btel-c", "pq"])
    n = 300 if quick else None
    jobs = [dict(name=name, budget=b, n_places=n) for b in budgets for name in methods]
    rows = [row for row, _ in fit_rows(data, jobs, desc="vs-budget")]
    return ExperimentRun("vs-budget", rows, out)
