"""(d) BTE-C with feature ratio c = d'/d = 0.1 … 1 at r = 1 (no budget; the bytes are reported)."""

from __future__ import annotations

from pathlib import Path

from ..evaluation.plots import NORDLAND_CREDIT, plot_parameter_sweep
from ._common import ExperimentRun, NordlandData, fit_rows, full_or_quick

__all__ = ["exp_feature_ratio", "plot"]


def exp_feature_ratio(data: NordlandData, out: Path, quick: bool) -> ExperimentRun:
    """(d) BTE-C with c = 0.1 … 1 at r = 1 (no budget; bytes reported)."""
    ratios = full_or_quick(quick, [0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9, 1.0], [0.1, 0.3])
    n = 300 if quick else None
    jobs = [dict(name="btel-c", budget=None, n_places=n, params={"feature_ratio": c}, label=f"BTE-C c={c:g}",
                 extra={"feature_ratio": c}) for c in ratios]
    return ExperimentRun("feature-ratio", fit_rows(data, jobs, desc="feature-ratio"), out, plot=plot)


def plot(run: ExperimentRun, out: Path) -> list[Path]:
    """recall@t against the feature ratio, one line per tolerance."""
    path = out / "recall_vs_feature_ratio.png"
    plot_parameter_sweep(run.rows, path, x_key="feature_ratio", xlabel="feature ratio c = d'/d",
                         title="BTE-C, r = 1", credit=NORDLAND_CREDIT)
    return [path]
