"""(a) Recall vs tolerance t = 0…80 at ≤ 2 MB, N = 2000, summer→winter and winter→summer, every method."""

from __future__ import annotations

from pathlib import Path

from ..evaluation.plots import NORDLAND_CREDIT, curve_label, plot_curves
from ..core.storage import format_bytes
from ._common import SEASONS, ExperimentRun, NordlandData, fit_rows, full_or_quick
from ..methods.roles import REFERENCE_METHOD

__all__ = ["exp_accuracy", "plot"]


def exp_accuracy(data: NordlandData, out: Path, quick: bool) -> ExperimentRun:
    """(a) recall vs tolerance at ≤ 2 MB, N = 2000, both directions, all methods."""
    n = 300 if quick else 2000
    budget = "50KB" if quick else "2MB"
    methods = full_or_quick(quick, ["btel-c", "btel-f", "btel-r", "pq", "opq", "itq", "ryth", "seqslam", "bruteforce"],
                            ["btel-c", "btel-r", "pq", "bruteforce"])
    rows, curves = [], {}
    jobs = [dict(name=name, budget=None if name == REFERENCE_METHOD else budget, n_places=n,
                 map_season=map_season)
            for map_season in SEASONS for name in methods]
    for job, record in zip(jobs, fit_rows(data, jobs, desc="accuracy")):
        map_season, name = job["map_season"], job["name"]
        direction = f"{map_season}→{SEASONS[1 - SEASONS.index(map_season)]}"
        record.labels["direction"] = direction
        record.columns += ("direction",)
        rows.append(record)
        if record.ok:
            curves[f"{name} {direction}"] = record.recall_curve.tolist()
    return ExperimentRun("accuracy", rows, out, curves, plot=plot)


def plot(run: ExperimentRun, out: Path) -> list[Path]:
    """recall@t curves, one figure per direction.

    The budget and N in the title are the ones the rows were run with (2 MB and 2000 in the full
    run, 50 KB and 300 in --quick), never a fixed text.
    """
    budgets = sorted({int(r.budget) for r in run.rows if r.budget})
    budget_text = ", ".join(format_bytes(b) for b in budgets) or "no budget"
    n_text = ", ".join(str(n) for n in sorted({int(r.n_map) for r in run.rows if r.n_map is not None}))
    sequence = {r.name for r in run.rows if r.uses_query_sequence}
    written = []
    for direction in sorted({k.split(" ", 1)[1] for k in run.curves}):
        curves = {curve_label(k.split(" ", 1)[0], sequence): v for k, v in run.curves.items() if k.endswith(direction)}
        path = out / f"recall_vs_tolerance_{direction.replace('→', '_to_')}.png"
        plot_curves(curves, path, title=f"Nordland {direction}, N = {n_text}, ≤ {budget_text} "
                                        "(brute force: reference, unbudgeted)", credit=NORDLAND_CREDIT, ylabel="recall@t")
        written.append(path)
    return written
