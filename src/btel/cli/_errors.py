"""Errors in the command line's words, and the exit status of each kind.

The library names its own API in messages (``fit_on=``, ``key=``, ``dtype='float16'``,
``BTELocalizer.fit(...)``): right for a Python user, wrong for someone typing ``btel``. When an
error reaches the command line its message is rewritten here, phrase by phrase, into the options
that do the same thing. A phrase not listed is shown as it is.

:func:`exit_status` sorts an error into the statuses below (shared by every command): what the user
gave (options, parameters, input files, an existing output) exits 2, what went wrong while
running exits 1.
"""

from __future__ import annotations

import csv
import re
import zipfile

import click

#: Exit status of every command (module docstring of :mod:`btel.cli`): a failure while running (a fit that
#: raised, a disk that filled up, a missing optional package) …
EXIT_FAILURE = 1
#: … a usage or input error (an unknown option or parameter, a bad value, an unreadable or hostile input
#: file, an output that exists without --overwrite): nothing was run, fix the command line …
EXIT_USAGE = 2
#: … after Ctrl-C (128 + SIGINT, what a shell reports for an interrupted program).
EXIT_INTERRUPTED = 130
#: … after SIGTERM (128 + 15: ``timeout``, SLURM's time limit, ``docker stop``), handled as Ctrl-C is:
#: finished rows stay on disk and ``--resume`` goes on.
EXIT_TERMINATED = 143
#: … when the reader of stdout went away (a closed pipe: ``btel … | head``): 128 + SIGPIPE, what a shell
#: reports for a Unix tool that stopped the same way; nothing is printed.
EXIT_BROKEN_PIPE = 141
#: Key of ``click.Context.meta`` set when stdout's reader went away during a run (``_jobs._echo_while_running``):
#: the command ends with :data:`EXIT_BROKEN_PIPE` once its run folder is written, as ``btel train`` does
#: after saving its model.
STDOUT_CLOSED = "btel.stdout_closed"
#: A finished evaluate/demo run in which some row did not fit or failed: the run folder is written and each
#: such row says why, but not every row was measured (docs/decisions/cli-exit-codes.md).
EXIT_SOME_ROWS_FAILED = EXIT_FAILURE

#: Library errors that end a command with one line (besides btel's own): what a hostile or damaged
#: input file can raise from a library (zip, csv, deep nesting, huge numbers, missing keys), and what
#: running can (a full disk, memory).
LIBRARY_ERRORS = (OSError, ValueError, zipfile.BadZipFile, csv.Error, RecursionError, OverflowError,
                  LookupError, MemoryError, EOFError)
#: OSErrors that are about a path the user gave, not about the machine (a full disk, an I/O error).
_PATH_ERRORS = (FileNotFoundError, FileExistsError, IsADirectoryError, NotADirectoryError, PermissionError)


class InputError(click.ClickException):
    """A usage or input error found while running (a file's content, a run folder): one line, exit 2,
    without the usage text a click.UsageError prints."""

    exit_code = EXIT_USAGE


def exit_status(exc: BaseException) -> int:
    """2 for an error in what the user gave, 1 for a failure while running (module docstring)."""
    from ..exceptions import BTELError, BudgetExceededError, InvalidAnswerError, MissingDependencyError

    if isinstance(exc, (BudgetExceededError, InvalidAnswerError, MissingDependencyError, MemoryError)):
        return EXIT_FAILURE  # a method's bug, a damaged answer, a missing package, the machine
    if isinstance(exc, OSError) and not isinstance(exc, (BTELError, *_PATH_ERRORS)):
        return EXIT_FAILURE  # a full disk, an I/O error
    cause = exc.__cause__
    if isinstance(exc, BTELError) and isinstance(cause, OSError) and not isinstance(cause, (BTELError, *_PATH_ERRORS)):
        return EXIT_FAILURE  # btel's message around a full disk or an I/O error (a model that could not be saved)
    return EXIT_USAGE

#: (library phrase, command-line phrase): regular expressions, applied in order.
CLI_WORDS: tuple[tuple[str, str], ...] = (
    (r"Train one with `btel train` or, in Python, model\.fit\(X\)\.save\(path\)",
     "Train one with `btel train DB -o MODEL`"),
    (r"pass fit_on=<map images>", "pass --fit-on MAP_IMAGES_DIR"),
    (r"\bfit_on=", "--fit-on "),
    (r"use dtype='float16'", "use --param dtype=float16"),
    (r"(\S+\.npz):(\S+) on the command line, key='[^']*' in Python", r"\1:\2"),
    (r"choose one with key=\.?", "choose one with FILE.npz:KEY."),
    (r"\bn_regions='auto'", "--regions auto"),
    (r"Pass overwrite=True \(CLI: --overwrite\)", "Give --overwrite"),
    (r"pass overwrite=True \(CLI: --overwrite\)", "give --overwrite"),
    (r"every row of X points", "every row of the map points"),
    (r"fit with normalize='none'", "fit with --param normalize=none"),
)


def cli_message(message: str) -> str:
    """``message`` with every library phrase of :data:`CLI_WORDS` replaced by its command-line phrase."""
    for pattern, replacement in CLI_WORDS:
        message = re.sub(pattern, replacement, message)
    return message


_BARE_NUMBER = re.compile(r"\s*(\d*\.?\d+(?:[eE][+-]?\d+)?)\s*")


def unitless_budget_hint(text: str) -> str | None:
    """For a positive budget written without a unit and under 1000 (``32``, ``1e2``), the budget it
    most likely means (``32KB``); else None. Such a number of bytes holds no useful map, so it is
    taken for a missing unit; ``32B`` says bytes explicitly, and a unitless number from 1000 up is
    read as bytes. Zero gets no hint: no unit makes it a budget."""
    match = _BARE_NUMBER.fullmatch(text)
    if match is None or not 0 < float(match.group(1)) < 1000:
        return None
    return f"{match.group(1)}KB"


class Terminated(KeyboardInterrupt):
    """SIGTERM, raised where the signal arrives (as Python raises KeyboardInterrupt for SIGINT), so that
    every clean-up written for Ctrl-C runs: a run's finished rows are written, its folder released."""


def exit_for_interrupt(exc: KeyboardInterrupt) -> int:
    """130 for Ctrl-C, 143 for SIGTERM."""
    return EXIT_TERMINATED if isinstance(exc, Terminated) else EXIT_INTERRUPTED

