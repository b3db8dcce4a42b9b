"""Several methods measured into one run folder: the jobs, the checks before fitting, the run.

:func:`run_methods` is "run these methods into a run folder" (``btel evaluate`` and ``btel demo``
call it): :func:`make_jobs` turns method names, budgets and parameters into :class:`Job` rows (the
unbudgeted reference added), :func:`evaluate_all` checks every job against its budget before
fitting any (:func:`preflight`), measures each in turn with :func:`~btel.evaluation.measure.measure`
— a method that does not fit or fails becomes a row with its status and reason — and a
:class:`~btel.evaluation.runs.RunWriter` writes each row as it finishes, so Ctrl-C keeps what is done.
"""

from __future__ import annotations

import logging
import sys
from collections.abc import Callable, Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

from ..core.storage import format_bytes
from ..core.validation import check_descriptors
from ..exceptions import BTELError, BudgetTooSmallError, InvalidParameterError
from .inputs import Job, make_jobs
from .measure import _tolerances_for, measure
from .metrics import DEFAULT_KS, TruthLike, check_ground_truth
from .records import STATUS_FAILED, STATUS_NOT_RUN, STATUS_REFUSED, EvaluationResult
from .tables import format_calibration, format_table, terminal_width

__all__ = ["preflight", "evaluate_all", "run_methods"]

logger = logging.getLogger(__name__)



def _budget_check(method: Any, n_rows: int, n_features: int, budget: int | None) -> None:
    """Raise what the method's own fit would raise for this map shape and budget, without fitting:
    the method answers (:meth:`btel.methods.base.PlaceLocalizer.check_budget`, its own planner). An object
    outside btel's base class without that method is left to its fit."""
    check = getattr(method, "check_budget", None)
    if check is not None:
        check(n_rows, n_features, budget)


def preflight(jobs: Sequence[Job], n_map: int | None, n_features: int | None, *,
              queries_are_route: bool = True) -> dict[str, EvaluationResult]:
    """Every row that cannot run, found before anything is fitted, by job name.

    - a job whose method does not fit its budget (the method's own planning rules applied to the
      map's shape) → status ``"does not fit"`` with the method's message and minimum bytes;
    - a job whose parameters cannot work on this map (too few places for its regions, periods or
      sub-quantisers) → ``"failed"``;
    - a method that uses the query sequence when ``queries_are_route`` is False → ``"refused"``.

    Jobs of already fitted methods are only checked for the last rule.

    Returns
    -------
    dict of str to EvaluationResult
        Only the jobs that will not run; every other job is left to :func:`evaluate_all`.
    """
    out: dict[str, EvaluationResult] = {}
    for job in jobs:
        common = dict(method=job.method, n_map=n_map, budget=job.budget, reference=job.reference)
        if not queries_are_route and getattr(job.method, "uses_query_sequence", False):
            out[job.name] = EvaluationResult.not_measured(
                job.name, STATUS_REFUSED,
                "uses the query sequence (SeqSLAM or a delta front end), but the query rows are independent "
                "places, not a route", **common)
            continue
        if not job.fit or n_map is None or n_features is None:
            continue
        try:
            _budget_check(job.method, int(n_map), int(n_features), job.budget)
        except BudgetTooSmallError as exc:
            out[job.name] = EvaluationResult.does_not_fit(job.name, exc, **common)
        except BTELError as exc:
            out[job.name] = EvaluationResult.not_measured(job.name, STATUS_FAILED, _short_reason(exc),
                                                          **common)
    return out


def _short_reason(exc: BaseException) -> str:
    """An exception as one line: its message (its type when it has none)."""
    message = " ".join(str(exc).split())
    return message or type(exc).__name__


def evaluate_all(
    jobs: Sequence[Job],
    X_map: Any,
    Q: Any,
    *,
    ground_truth: TruthLike = None,
    tolerances: Iterable[int] | None = None,
    ks: Iterable[int] = DEFAULT_KS,
    k_tolerance: int = 0,
    curve_max: int | None = None,
    queries_are_route: bool = True,
    on_preflight: Callable[[dict[str, EvaluationResult]], None] | None = None,
    on_result: Callable[[list[EvaluationResult]], None] | None = None,
    on_start: Callable[[int, Job], None] | None = None,
    finished: Sequence[EvaluationResult] = (),
    timing_threads: int | None = 1,
) -> list[EvaluationResult]:
    """Evaluate every job; one that does not fit or fails becomes a row, never an abort.

    Order of work: the ground truth is checked against the query and map counts, then
    :func:`preflight` finds every row that cannot run (all of them, reported at once through
    ``on_preflight``), then each remaining job is fitted and measured in turn. A
    :class:`~btel.exceptions.BudgetTooSmallError` the preflight could not foresee becomes a
    ``"does not fit"`` row, any other error of btel, numpy or faiss (``ValueError``,
    ``RuntimeError``, ``MemoryError``, ``OSError``) a ``"failed"`` row, and the next job runs.
    After each job ``on_result`` receives every row so far, in job order (write them there: a
    crash or Ctrl-C then keeps what is done). On Ctrl-C the rows not yet run become ``"not run"``,
    ``on_result`` sees them, and the ``KeyboardInterrupt`` propagates.

    Parameters
    ----------
    jobs : sequence of Job
        Distinct names.
    X_map : array-like of shape (n_map, n_features) or None
        Map descriptors (None when every job is already fitted).
    Q : array-like of shape (n_queries, n_features)
    ground_truth, tolerances, ks, k_tolerance, curve_max
        As in :func:`~btel.evaluation.measure.measure`.
    queries_are_route : bool, default True
        False says the query rows are independent places, not a traverse: methods that use the
        query sequence are refused.
    on_preflight : callable, optional
        Called once with the rows that will not run (may be empty), before any fit.
    on_result : callable, optional
        Called with the list of rows so far after each job.
    on_start : callable, optional
        Called with (index, job) before a job is fitted (progress display).
    timing_threads : int or None, default 1
        Threads while localizing and timing each method (:func:`time_queries`).
    finished : sequence of EvaluationResult, optional
        Rows of an earlier, interrupted run of the same jobs (``btel evaluate --resume``): a job
        with a row of status ``"ok"`` here is not run again; that row is kept.

    Returns
    -------
    list of EvaluationResult
        One per job, in job order.
    """
    names = [job.name for job in jobs]
    if len(set(names)) != len(names):
        raise InvalidParameterError(f"job names must be distinct; got {names}.")
    if X_map is not None:
        X_map = check_descriptors(X_map, name="X_map")
    n_map = X_map.shape[0] if X_map is not None else next(
        (int(j.method.n_places_) for j in jobs if not j.fit and hasattr(j.method, "n_places_")), None)
    n_features = X_map.shape[1] if X_map is not None else None
    Q = check_descriptors(Q, name="Q", n_features=n_features)
    gt = check_ground_truth(ground_truth, Q.shape[0], n_map)
    tolerances = _tolerances_for(tolerances, gt, n_map)
    skipped = preflight(jobs, n_map, n_features, queries_are_route=queries_are_route)
    for job in jobs:
        if job.name in skipped:
            skipped[job.name].series = job.series
            skipped[job.name].settings = job.settings
    if on_preflight is not None:
        on_preflight(skipped)
    done: dict[str, EvaluationResult] = dict(skipped)
    done.update({r.name: r for r in finished if r.ok and r.name in names})

    def rows() -> list[EvaluationResult]:
        return [done[name] for name in names if name in done]

    for index, job in enumerate(jobs):
        if job.name in done:
            continue
        common = dict(method=job.method, n_map=n_map, n_queries=Q.shape[0], budget=job.budget,
                      reference=job.reference)
        if on_start is not None:
            on_start(index, job)
        try:
            done[job.name] = measure(job.method, X_map if job.fit else None, Q, ground_truth=gt,
                                     tolerances=tolerances or None, ks=ks, k_tolerance=k_tolerance,
                                     name=job.name, curve_max=curve_max, fit=job.fit, budget=job.budget,
                                     reference=job.reference, timing_threads=timing_threads,
                                     fit_params=job.fit_params)
        except BudgetTooSmallError as exc:
            done[job.name] = EvaluationResult.does_not_fit(job.name, exc, **common)
        except KeyboardInterrupt:
            for later in jobs[index:]:
                if later.name not in done:
                    done[later.name] = EvaluationResult.not_measured(
                        later.name, STATUS_NOT_RUN, "interrupted (Ctrl-C) before it finished",
                        method=later.method, n_map=n_map, n_queries=Q.shape[0], budget=later.budget,
                        reference=later.reference)
                    done[later.name].series = later.series
            if on_result is not None:
                on_result(rows())
            raise
        except (ValueError, RuntimeError, MemoryError, OSError, ArithmeticError) as exc:
            logger.debug("%s failed", job.name, exc_info=True)
            done[job.name] = EvaluationResult.not_measured(
                job.name, STATUS_FAILED, f"{type(exc).__name__}: {_short_reason(exc)}", **common)
        done[job.name].series = job.series
        done[job.name].settings = job.settings
        if on_result is not None:
            on_result(rows())
    return rows()



def run_methods(methods: Sequence[str | Job], X_map: Any, Q: Any, *, out: str | Path,
                budgets: Sequence[Any] = (None,), params: Mapping[str, Mapping[str, Any]] | None = None,
                reference: bool = True, ground_truth: TruthLike = None,
                tolerances: Iterable[int] | None = None,
                ks: Iterable[int] = (1, 5, 10, 20), queries_are_route: bool = True, title: str | None = None,
                extra: Mapping[str, Any] | None = None, overwrite: bool = False,
                finished: Sequence[EvaluationResult] | None = None,
                names: tuple[Sequence[str] | None, Sequence[str] | None] = (None, None),
                truth: Mapping[str, str] | None = None, progress: bool = True,
                timing_threads: int | None = 1, command: str | Sequence[str] | None = None,
                echo: Callable[..., None] | None = None) -> list[EvaluationResult]:
    """Measure every method on one map and query set and write the run folder ``out`` as rows finish.

    Parameters
    ----------
    methods : sequence of str or Job
        Method names (made into jobs by :func:`make_jobs` with ``budgets``, ``params`` and
        ``reference``) and ready jobs (e.g. saved models, ``Job(name, model, fit=False)``); the
        ready jobs come first.
    X_map : array-like of shape (n_map, n_features) or None
        Map descriptors (None when every job is already fitted).
    Q : array-like of shape (n_queries, n_features)
    out : path
        The run folder (:class:`~btel.evaluation.runs.RunWriter`; refused when it holds a run and
        ``overwrite`` is False).
    ground_truth, tolerances, ks, queries_are_route
        As in :func:`evaluate_all`.
    title : str, optional
        The plots' title.
    extra : mapping, optional
        Run metadata written into ``metrics.json`` (data, budget, ground truth's source and rule).
    finished : sequence of EvaluationResult, optional
        Rows of an interrupted run of the same jobs to keep (``out`` is then written on, not replaced).
    names : (query names, map names)
        Image names written beside indices in the predictions files (None where unknown).
    truth : mapping, optional
        The ground truth's ``{"source", "rule"}`` (:func:`btel.datasets.sources.resolve_ground_truth`),
        written into every row and the run's metadata; default: frame-aligned when ``ground_truth``
        is None, else its kind's rule with the source "given in Python".
    progress : bool
        A progress bar on stderr (one line per job instead when ``echo`` is given and stderr is no
        terminal).
    command : str or sequence of str, optional
        The command line recorded (default ``sys.argv``).
    echo : callable, optional
        ``echo(text)`` / ``echo(text, err=True)`` receives what a command line prints (rows that
        cannot run, the table, where the files are); None prints nothing.

    Returns
    -------
    list of EvaluationResult
        One per job, in job order.

    Raises
    ------
    KeyboardInterrupt
        After the finished rows and their plots are written (``metrics.json`` stays incomplete).
    """
    from tqdm import tqdm

    from .resume import resume_writer
    from .runs import RunWriter

    from ..datasets.sources import truth_description

    say = echo or (lambda *args, **kwargs: None)
    if truth is None:
        gt = None if ground_truth is None else check_ground_truth(ground_truth, len(Q), None)
        truth = (truth_description(None, "frame-aligned (query j is place j)") if gt is None
                 else truth_description(gt, "given in Python"))
    truth = dict(truth)
    extra = {**(extra or {}), "ground_truth": truth}
    jobs = [m for m in methods if isinstance(m, Job)]
    named = [m for m in methods if not isinstance(m, Job)]
    jobs += make_jobs(named, budgets, params, reference=reference) if named else []
    out = Path(out)
    if finished is not None:
        writer = resume_writer(out, finished, command=command, extra=extra)
    else:
        writer = RunWriter(out, command=command, extra=extra, overwrite=overwrite)
    writer.query_names, writer.db_names = names
    unit = "frames" if queries_are_route else "map places"
    bar = tqdm(total=len(jobs), unit="method", disable=None if progress else True, leave=False,
               file=sys.stderr)

    # The "[n/total]" lines count the rows that run: a row refused before fitting, or done before a
    # resume, is not one, so the count has no gap.
    count = {"started": 0, "total": len(jobs)}

    def on_preflight(skipped: dict[str, EvaluationResult]) -> None:
        if skipped:
            say(f"{len(skipped)} of {len(jobs)} rows cannot run "
                "(found before fitting; every other row runs):")
            for name, r in skipped.items():
                say(f"  {name}: {r.status}: {r.reason}")
        kept = set(skipped) | {r.name for r in finished or () if r.ok}
        count["total"] = sum(job.name not in kept for job in jobs)
        bar.update(len(jobs) - count["total"])

    def on_start(index: int, job: Job) -> None:
        budget = ("reference, unbudgeted" if job.reference else
                  format_bytes(job.budget) if job.budget else "no budget")
        count["started"] += 1
        if bar.disable:
            doing = "fitting" if job.fit else "evaluating"
            say(f"[{count['started']}/{count['total']}] {doing} {job.name} ({budget}) …")
        else:
            bar.set_description_str(f"{job.name} ({budget})")

    latest: list[EvaluationResult] = []

    def on_result(rows: list[EvaluationResult]) -> None:
        for row in rows:
            row.truth = truth
        latest[:] = rows
        writer.write(rows)
        if rows and not bar.disable:
            bar.update(1)

    try:
        results = evaluate_all(jobs, X_map, Q, ground_truth=ground_truth, tolerances=tolerances, ks=ks,
                               queries_are_route=queries_are_route, on_preflight=on_preflight,
                               on_result=on_result, on_start=on_start, finished=finished or (),
                               timing_threads=timing_threads)
    except KeyboardInterrupt:
        bar.close()
        _plot_partial_run(latest, out, title or out.name, unit, say)
        writer.close()
        say(f"interrupted: the finished rows are in {out}/metrics.csv", err=True)
        raise
    except BaseException:  # a full disk, a failed write: the rows on disk stay, the claim goes
        writer.close()
        raise
    bar.close()
    for row in results:
        row.truth = truth
    say(format_table(results, width=terminal_width()))
    calibration = format_calibration(results)
    if calibration:
        say(calibration)
    report = writer.finish(results, title=title, tolerance_unit=unit)
    say(f"run folder: {report.out_dir}")
    failed = [r for r in results if not r.ok]
    if failed:
        which = "; ".join(f"{r.name} ({r.status})" for r in failed)
        say(f"{len(failed)} of {len(results)} rows did not run: {which}; see their reason in the table.",
            err=True)
    return results


def _plot_partial_run(rows: list[EvaluationResult], out: Path, title: str, unit: str,
                      say: Callable[..., None]) -> None:
    """The plots of the rows that finished before Ctrl-C (metrics.json stays ``"complete": false``)."""
    from .plots import plot_run

    measured = [r for r in rows if r.ok]
    if not measured:
        return
    try:
        plot_run(measured, out, title=f"{title} — interrupted: {len(measured)} of {len(rows)} rows",
                 tolerance_unit=unit)
    except (ValueError, OSError) as exc:  # the rows on disk matter more than a figure
        say(f"Warning: the plots of the partial run could not be drawn ({exc})", err=True)
