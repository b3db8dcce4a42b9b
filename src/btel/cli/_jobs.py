"""Methods by name with their parameters, one job per (method, budget), and the run that evaluates them.

``--param`` values are checked against each method's ``get_params()`` before anything is fitted;
the jobs go to :func:`btel.evaluation.evaluate_all`, whose rows a :class:`btel.evaluation.runs.RunWriter`
writes as they finish (``demo`` and ``evaluate`` share all of it).
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

import click

from ._options import EXIT_INTERRUPTED, _command_line
from ._params import RUNTIME_PARAMS, _naming, _params_by_method

if TYPE_CHECKING:  # numpy is imported by the commands that need it: `btel --help` does not wait for it
    import numpy as np


def _fit_jobs(names: list[str], budgets: list[str | None], param_texts: tuple[str, ...], *,
              reference: bool, shortcuts: dict[str, tuple[str, Any]] | None = None) -> list[Any]:
    """One job per (method, budget); the reference method (brute force) once, unbudgeted, as the reference row.

    The rule (the same in demo and evaluate): brute force stores every map descriptor, so it is the
    upper reference, not a contender under the budget. It is run without a budget unless
    ``--param METHOD:budget=…`` names it and asks for one. Which method it is,
    :data:`btel.methods.registry.REFERENCE_METHOD` says. When the reference was added (not named in
    ``--methods``), the same search on shrinkage-whitened rows
    (:data:`btel.methods.roles.WHITENED_REFERENCE`) is a second reference row beside it, with the same
    parameters, so the table shows which front end the map favours.
    """
    from ..methods.roles import WHITENED_REFERENCE
    from ..evaluation.measure import Job
    from ..methods.registry import REFERENCE_METHOD, make_method

    added_reference = reference and REFERENCE_METHOD not in names
    if added_reference:
        names = [*names, REFERENCE_METHOD]
    params = _params_by_method(names, param_texts, shortcuts=shortcuts)
    jobs = []
    for name in names:
        is_reference = name == REFERENCE_METHOD and "budget" not in params[name]
        for budget in ([None] if is_reference else budgets):
            label = name if len(budgets) == 1 or is_reference else f"{name}@{budget}"
            kwargs = dict(params[name])
            if budget is not None and "budget" not in kwargs:
                kwargs["budget"] = budget
            settings = {k: v for k, v in params[name].items() if k != "budget" and k not in RUNTIME_PARAMS}
            with _naming(name):
                jobs.append(Job(label, make_method(name, **kwargs), reference=is_reference, series=name,
                                settings=settings or None))
    white_label, white_params = WHITENED_REFERENCE
    reference_params = params.get(REFERENCE_METHOD, {})
    # A front end or budget given to the reference by --param is the user's own reference: no second row.
    if added_reference and not set(white_params) & set(reference_params) and "budget" not in reference_params:
        kwargs = {**reference_params, **white_params}
        settings = {k: v for k, v in kwargs.items() if k not in RUNTIME_PARAMS}
        with _naming(REFERENCE_METHOD):
            jobs.append(Job(white_label, make_method(REFERENCE_METHOD, **kwargs), reference=True,
                            series=white_label, settings=settings))
    return jobs


def _run_jobs(jobs: list[Any], X: Any, Q: np.ndarray, *, ground_truth: Any, out: Path, overwrite: bool, title: str,
              extra: dict[str, Any], progress: bool, tolerances: list[int] | None = None,
              finished: list[Any] | None = None, timing_threads: int | None = 1, pairs: tuple[dict[str, Path], list[str], list[str]] | None = None,
              names: tuple[list[str] | None, list[str] | None] = (None, None),
              ks: list[int] | tuple[int, ...] = (1, 5, 10, 20), queries_are_route: bool = True) -> bool:
    """Run every job through :func:`btel.evaluation.evaluate_all`, writing the run folder as rows finish.

    Prints the rows that cannot run before fitting anything, a progress bar (or one line per job
    off a terminal), the table and where the files are. Returns True when some row did not run.
    """
    from tqdm import tqdm

    from ..evaluation.measure import evaluate_all, format_table
    from ..evaluation.runs import RunWriter
    from ..core.storage import format_bytes

    if finished is not None:  # --resume: the finished rows and their predictions stay
        from ..evaluation.runs import resume_writer

        writer = resume_writer(out, finished, command=_command_line(), extra=extra)
    else:
        writer = RunWriter(out, command=_command_line(), extra=extra, overwrite=overwrite)
    writer.query_names, writer.db_names = names  # image names in the predictions files
    unit = "frames" if queries_are_route else "map places"  # no "frames" on independent places
    bar = tqdm(total=len(jobs), unit="method", disable=None if progress else True, leave=False, file=sys.stderr)

    def on_preflight(skipped: dict[str, Any]) -> None:
        if skipped:
            click.echo(f"{len(skipped)} of {len(jobs)} rows cannot run (found before fitting; every other row runs):")
            for name, r in skipped.items():
                click.echo(f"  {name}: {r.status}: {r.reason}")
            bar.update(len(skipped))

    def on_start(index: int, job: Any) -> None:
        budget = job.budget
        what = f"{job.name} ({'reference, unbudgeted' if job.reference else format_bytes(budget) if budget else 'no budget'})"
        if bar.disable:
            click.echo(f"[{index + 1}/{len(jobs)}] {'fitting' if job.fit else 'evaluating'} {what} …")
        else:
            bar.set_description_str(what)

    latest: list[Any] = []

    def on_result(rows: list[Any]) -> None:
        latest[:] = rows
        writer.write(rows)
        if rows and not bar.disable:
            bar.update(1)

    try:
        results = evaluate_all(jobs, X, Q, ground_truth=ground_truth, tolerances=tolerances, ks=ks,
                               queries_are_route=queries_are_route, on_preflight=on_preflight, on_result=on_result,
                               on_start=on_start, finished=finished or (), timing_threads=timing_threads)
    except KeyboardInterrupt:
        bar.close()
        _plot_partial_run(latest, out, title, unit)
        writer.close()
        click.echo(f"interrupted: the finished rows are in {out}/metrics.csv", err=True)
        raise click.exceptions.Exit(EXIT_INTERRUPTED) from None
    except BaseException:  # a full disk, a failed write: the rows on disk stay, the claim goes
        writer.close()
        raise
    bar.close()
    click.echo(format_table(results))
    report = writer.finish(results, title=title, tolerance_unit=unit)
    click.echo(f"run folder: {report.out_dir}")
    from ._gallery import galleries_after_run

    galleries_after_run(out, extra)
    if pairs is not None:
        from ._names import write_pairs

        targets, q_names, db_names = pairs
        for r in results:
            if r.name in targets and r.ok and r.ranked is not None:
                n = write_pairs(targets[r.name], r.ranked, q_names, db_names, overwrite=overwrite)
                click.echo(f"pairs ({r.name}, top {r.ranked.shape[1]}): {n} lines written to {targets[r.name]}")
    failed = [r for r in results if not r.ok]
    if failed:
        click.echo(f"{len(failed)} of {len(results)} rows did not run: "
                   + "; ".join(f"{r.name} ({r.status})" for r in failed) + "; see their reason in the table.", err=True)
    return bool(failed)


def _plot_partial_run(rows: list[Any], out: Path, title: str, unit: str = "frames") -> None:
    """The plots of the rows that finished before Ctrl-C (metrics.json stays ``"complete": false``)."""
    from ..evaluation.plots import plot_run

    measured = [r for r in rows if r.ok]
    if not measured:
        return
    try:
        plot_run(measured, out, title=f"{title} — interrupted: {len(measured)} of {len(rows)} rows",
                 tolerance_unit=unit)
    except (ValueError, OSError) as exc:  # the rows on disk matter more than a figure
        click.echo(f"Warning: the plots of the partial run could not be drawn ({exc})", err=True)
