"""What several commands share: help texts, exit statuses and the small option parsers (budgets, lists).

Nothing here imports numpy or a method at module level: every command module imports this one,
and ``btel --help`` loads them all.
"""

from __future__ import annotations

import os
import shlex
import sys
from typing import Any

import click

from ._errors import EXIT_FAILURE, EXIT_INTERRUPTED, EXIT_SOME_ROWS_FAILED, EXIT_USAGE  # noqa: F401 - shared


_VALUE_HELP = ("VALUE is read as JSON when it is a JSON literal (3, 0.5, true, null, \"x\"), else kept as text "
               "(auto, float16). `btel methods --params` lists every method's parameters.")
_PARAM_HELP = "A parameter of --method, NAME=VALUE (repeatable), e.g. --param sparsity=0.05. " + _VALUE_HELP
_PARAMS_HELP = ("A parameter NAME=VALUE of every method in --methods, or METHOD:NAME=VALUE of one of them "
                "(repeatable), e.g. --param btel-r:n_regions=10. " + _VALUE_HELP)
_N_JOBS_HELP = ("Parallel fits (-1 = all cores), for the methods with an n_jobs parameter; the others ignore it "
                "(a runtime flag: it changes how a method runs, not what it computes).")
_NO_PROGRESS_HELP = ("No progress bars (btel's own and those of the methods with a progress parameter; the others "
                     "ignore it).")
_TIMING_THREADS_HELP = ("BLAS/OpenMP threads while localizing and timing the queries (the table's 'threads'). Default 1: "
                        "on a shared machine multi-threaded calls spin against other processes and identical runs "
                        "differ by 2-100x; 0 leaves the libraries' own thread count.")


def timing_threads_option(ctx: click.Context, param: click.Parameter, value: int) -> int:
    """``--timing-threads``, refused above the machine's cores (the table would record threads never run)."""
    cores = os.cpu_count() or 1
    if value > cores:
        raise click.BadParameter(f"{value} threads, but this machine has {cores} cores; give 0 (the libraries' "
                                 f"own count) to {cores}.", ctx=ctx, param=param)
    return value


_BUDGET_HELP = ("Byte budget of every method but the brute-force reference, e.g. 500KB (KB = 1000 B, KiB = 1024 B); "
                "several, comma-separated (100KB,500KB), give one row per method and budget.")
_REFERENCE_HELP = ("Brute force (exact nearest neighbour over every map descriptor) is the unbudgeted reference: it is "
                   "always run without a budget, added when not in --methods (then also on shrinkage-whitened rows, "
                   "'bruteforce shrink'), and marked '*' in the table. --no-reference leaves it out.")
_ORDER_HELP = ("route: the query rows are consecutive frames of one traverse (methods that use the query sequence, "
               "SeqSLAM or a delta front end, may use their order; they are marked † in the table). independent: the "
               "rows are unrelated places, and sequence methods are refused.")
_DELTA_HELP = ("Delta (sequence) descriptors over W frames (Garg & Milford 2020): every method's front end turns a "
               "traverse into mean(last W frames) − mean(the W before), causally; queries are then one ordered "
               "traverse and the method is marked † (uses the query sequence). Same as --param delta=W.")
_FRONT_END_HELP = ("Front end of every method (default: rows L2-normalised, SeqSLAM: none): --normalize none|l2|power, "
                   "--whiten P (PCA-whitening to P dims, counted in the bytes), --delta W.")


def calibration_options(command: Any) -> Any:
    """``--calibrate QUERIES``, ``--calibrate-truth GT``, ``--calibrate-tolerance T`` (train, evaluate)."""
    for option in reversed([
        click.option("--calibrate", type=click.Path(dir_okay=False), default=None, metavar="QUERIES",
                     help="Labelled queries from your deployment conditions, for the methods that choose on "
                          "them (auto: every candidate scored, a switch only beyond noise); never stored."),
        click.option("--calibrate-truth", default=None, metavar="GT",
                     help="The ground truth of --calibrate (any form --ground-truth takes, utm included; "
                          "default frame-aligned)."),
        click.option("--calibrate-tolerance", type=click.IntRange(min=0), default=None, metavar="T",
                     help="With --calibrate and true places: correct within T places "
                          "(--param calibration_tolerance)."),
    ]):
        command = option(command)
    return command


def _runtime_shortcuts(no_progress: bool, n_jobs: int | None) -> dict[str, tuple[str, Any]]:
    """The runtime flags given, as shortcuts (parameter → (option, value)) for :func:`._jobs._params_by_method`."""
    out: dict[str, tuple[str, Any]] = {}
    if no_progress:
        out["progress"] = ("--no-progress", False)
    if n_jobs is not None:
        out["n_jobs"] = ("--n-jobs", n_jobs)
    return out


def _budgets(text: str) -> list[str]:
    """``"100KB, 500KB"`` → ``["100KB", "500KB"]``, each checked by :func:`btel.core.storage.parse_budget`."""
    budgets = [b.strip() for b in text.split(",") if b.strip()]
    if not budgets:
        raise click.UsageError("--budget is empty; give a byte budget such as 500KB.")
    for b in budgets:
        _check_budget(b)
    return budgets


def _check_budget(text: str) -> None:
    """A usage error for a budget that is not one, or a unitless number too small to be meant as bytes."""
    from ..core.storage import parse_budget
    from ._errors import unitless_budget_hint

    if "," in text:  # lists are split before this check, so a comma means a one-budget command
        raise click.UsageError(f"--budget {text.strip()}: this command fits one model, so it takes one budget; "
                               "run it once per budget, or use `btel evaluate --budget 64KB,128KB` for one row "
                               "per budget.")
    hint = unitless_budget_hint(text)
    if hint is not None:
        raise click.UsageError(f"--budget {text.strip()} has no unit, so it would mean {text.strip()} bytes; did you "
                               f"mean {hint}? Write {text.strip()}B if you mean bytes (KB = 1000 B, KiB = 1024 B).")
    try:
        parse_budget(text)
    except ValueError as exc:
        raise click.UsageError(f"--budget {text!r}: {exc}") from None


def _budget_text(budgets: list[str | None]) -> str:
    from ..core.storage import format_bytes, parse_budget

    given = [format_bytes(parse_budget(b)) for b in budgets if b]
    return ", ".join(given) if given else "none"


def _int_list(text: str, flag: str, *, minimum: int) -> list[int]:
    try:
        values = sorted({int(v) for v in text.split(",") if v.strip()})
    except ValueError:
        raise click.UsageError(f"{flag} takes comma-separated integers, e.g. 1,5,10; got {text!r}.") from None
    if not values or values[0] < minimum:
        raise click.UsageError(f"{flag} takes integers ≥ {minimum}; got {text!r}.")
    return values


def _split(methods: str) -> list[str]:
    names = [m.strip() for m in methods.split(",") if m.strip()]
    if not names:
        raise click.UsageError("--methods is empty; give at least one method name (see `btel methods`).")
    return names


def _command_line() -> str:
    return shlex.join(["btel", *sys.argv[1:]])
