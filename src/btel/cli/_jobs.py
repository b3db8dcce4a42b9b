"""``--param`` values checked per method, and the run of ``demo`` / ``evaluate``: the command line's side.

The values are checked against each method's ``get_params()`` before anything is fitted; the jobs
are :func:`btel.evaluation.make_jobs`'s and the run is :func:`btel.evaluation.run_methods`, which
this module calls with the command line's echo, exit status and files (galleries, pairs).
"""

from __future__ import annotations

import os
import sys
from pathlib import Path
from typing import Any

import click

from ._errors import STDOUT_CLOSED
from ._options import _command_line
from ._params import _params_by_method


def _fit_jobs(names: list[str], budgets: list[str | None], param_texts: tuple[str, ...], *,
              reference: bool, shortcuts: dict[str, tuple[str, Any]] | None = None) -> list[Any]:
    """The jobs of ``--methods`` × ``--budget`` with their ``--param`` values (``make_jobs``)."""
    from ..evaluation.inputs import make_jobs
    from ..methods.registry import REFERENCE_METHOD

    added = (REFERENCE_METHOD,) if reference and REFERENCE_METHOD not in names else ()
    params = _params_by_method([*names, *added], param_texts, shortcuts=shortcuts, added=added)
    return make_jobs(names, budgets, params, reference=reference)


def _run_jobs(jobs: list[Any], X: Any, Q: Any, *, out: Path, extra: dict[str, Any], progress: bool,
              pairs: tuple[dict[str, Path], list[str], list[str]] | None = None, **options: Any) -> bool:
    """:func:`btel.evaluation.run_methods` with the command line's echo (Ctrl-C: exit 130), then the
    galleries and ``--pairs`` files. True when some row did not run."""
    from ..evaluation.batch import run_methods
    from ..evaluation.runs import load_average
    from ._gallery import galleries_after_run

    load, cores = load_average(), os.cpu_count() or 1
    if load is not None and load[0] > cores:  # fit and query times then run slow, and vary from run to run
        _echo_while_running(f"note: the machine is busy (load average {load[0]:.1f} on {cores} cores): fit and "
                            "query times of this run are slower than on an idle machine; metrics.json records the load.")
    try:
        results = run_methods(jobs, X, Q, out=out, extra=extra, progress=progress, command=_command_line(),
                              echo=_echo_while_running, **options)
    except KeyboardInterrupt as exc:
        from ._errors import exit_for_interrupt

        raise click.exceptions.Exit(exit_for_interrupt(exc)) from None
    galleries_after_run(out, extra)
    if pairs is not None:
        from ._names import write_pairs

        targets, q_names, db_names = pairs
        for r in results:
            if r.name in targets and r.ok and r.ranked is not None:
                n = write_pairs(targets[r.name], r.ranked, q_names, db_names, overwrite=options["overwrite"])
                _echo_while_running(f"pairs ({r.name}, top {r.ranked.shape[1]}): {n} lines in {targets[r.name]}")
    return any(not r.ok for r in results)


def _echo_while_running(message: Any = None, err: bool = False, **kwargs: Any) -> None:
    """``click.echo`` that lets a run go on when the reader of stdout went away (``btel evaluate … | head``):
    the run folder is what the command makes, so stdout is pointed at /dev/null, the run finishes, and
    the command exits 141 afterwards (:data:`._errors.STDOUT_CLOSED`)."""
    try:
        click.echo(message, err=err, **kwargs)
    except BrokenPipeError:
        if err:
            raise
        context = click.get_current_context(silent=True)
        if context is not None:
            context.meta[STDOUT_CLOSED] = True
        try:
            os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        except (AttributeError, ValueError, OSError):  # a stdout without a descriptor (a test runner's)
            return
        click.echo("note: standard output was closed; the run goes on and writes its folder.", err=True)
