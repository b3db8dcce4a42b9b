"""(b) Recall@10 vs the number of places N = 64 … 3576 at ≤ 0.5 MB (summer → winter)."""

from __future__ import annotations

from pathlib import Path

from ._common import ExperimentRun, NordlandData, fit_rows, full_or_quick

__all__ = ["exp_vs_n"]


def exp_vs_n(data: NordlandData, out: Path, quick: bool) -> ExperimentRun:
    """(b) recall@10 vs N at ≤ 0.5 MB."""
    sizes = full_or_quick(quick, [64, 128, 256, 512, 1024, 2048, 3576], [64, 256])
    methods = full_or_quick(quick, ["btel-c", "btel-r", "pq", "opq", "ryth"], ["btel-c", "pq"])
    budget = "50KB" if quick else "500KB"
    jobs = [dict(name=name, budget=budget, n_places=n) for n in sizes for name in methods]
    rows = [row for row, _ in fit_rows(data, jobs, desc="vs-n")]
    return ExperimentRun("vs-n", rows, out)
