"""(a) Recall vs tolerance t = 0…80 at ≤ 2 MB, N = 2000, summer→winter and winter→summer, every method."""

from __future__ import annotations

from pathlib import Path

from ._common import SEASONS, ExperimentRun, NordlandData, fit_rows, full_or_quick

__all__ = ["exp_accuracy"]


def exp_accuracy(data: NordlandData, out: Path, quick: bool) -> ExperimentRun:
    """(a) recall vs tolerance at ≤ 2 MB, N = 2000, both directions, all methods."""
    n = 300 if quick else 2000
    budget = "50KB" if quick else "2MB"
    methods = full_or_quick(quick, ["btel-c", "btel-f", "btel-r", "pq", "opq", "itq", "ryth", "seqslam", "bruteforce"],
                            ["btel-c", "btel-r", "pq", "bruteforce"])
    rows, curves = [], {}
    jobs = [dict(name=name, budget=None if name == "bruteforce" else budget, n_places=n, map_season=map_season)
            for map_season in SEASONS for name in methods]
    for job, (row, result) in zip(jobs, fit_rows(data, jobs, desc="accuracy")):
        map_season, name = job["map_season"], job["name"]
        row["direction"] = f"{map_season}→{SEASONS[1 - SEASONS.index(map_season)]}"
        rows.append(row)
        if result is not None:
            curves[f"{name} {row['direction']}"] = result.recall_curve.tolist()
    return ExperimentRun("accuracy", rows, out, curves)
