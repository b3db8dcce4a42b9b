"""(e) BTEL with r = 1 … 20 regions at c = 0.1 (no budget; the bytes are reported)."""

from __future__ import annotations

from pathlib import Path

from ..evaluation.plots import NORDLAND_CREDIT, plot_parameter_sweep
from ._common import ExperimentRun, NordlandData, fit_rows, full_or_quick

__all__ = ["exp_regions", "plot"]


def exp_regions(data: NordlandData, out: Path, quick: bool) -> ExperimentRun:
    """(e) BTEL with r = 1 … 20 at c = 0.1 (no budget; bytes reported)."""
    counts = full_or_quick(quick, [1, 2, 5, 10, 15, 20], [1, 4])
    n = 300 if quick else None
    jobs = [dict(name="btel-c", budget=None, n_places=n, params={"feature_ratio": 0.1, "n_regions": r},
                 label=f"BTEL r={r}", extra={"n_regions": r}) for r in counts]
    return ExperimentRun("regions", fit_rows(data, jobs, desc="regions"), out, plot=plot)


def plot(run: ExperimentRun, out: Path) -> list[Path]:
    """recall@t against the number of regions, one line per tolerance."""
    path = out / "recall_vs_regions.png"
    plot_parameter_sweep(run.rows, path, x_key="n_regions", xlabel="regions r", title="BTEL, c = 0.1",
                         credit=NORDLAND_CREDIT)
    return [path]
