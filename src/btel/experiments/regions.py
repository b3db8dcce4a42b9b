"""(e) BTEL with r = 1 … 20 regions at c = 0.1 (no budget; the bytes are reported)."""

from __future__ import annotations

from pathlib import Path

from ._common import ExperimentRun, NordlandData, fit_rows, full_or_quick

__all__ = ["exp_regions"]


def exp_regions(data: NordlandData, out: Path, quick: bool) -> ExperimentRun:
    """(e) BTEL with r = 1 … 20 at c = 0.1 (no budget; bytes reported)."""
    counts = full_or_quick(quick, [1, 2, 5, 10, 15, 20], [1, 4])
    n = 300 if quick else None
    jobs = [dict(name="btel-c", budget=None, n_places=n, params={"feature_ratio": 0.1, "n_regions": r},
                 label=f"BTEL r={r}", extra={"n_regions": r}) for r in counts]
    rows = [row for row, _ in fit_rows(data, jobs, desc="regions")]
    return ExperimentRun("regions", rows, out)
