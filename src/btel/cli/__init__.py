"""The ``btel`` command line: from descriptors (or images) to a model, predictions and a recall report.

Every subcommand has ``--help``. Failures print one line ``Error: …`` on stderr, in the command
line's words, and exit with the same status in every command: 2 for a usage or input error (an
unknown option or parameter, a value its method refuses, an unreadable input file, an output that
exists without ``--overwrite``): nothing ran; 1 for a failure while running (a fit that raised, a
full disk; ``evaluate``/``demo`` also when the run finished but some row did not fit or failed: its
row says why); 130 after Ctrl-C; 143 after SIGTERM (handled as Ctrl-C is); 141, silently, when the reader of stdout went away (``| head``). No traceback unless ``BTEL_DEBUG=1``. Warnings (a distorting
resize, a capped PCA) print one line ``Warning: …`` on stderr.

Any parameter of any method is set with ``--param NAME=VALUE`` (``train``, ``evaluate``, ``demo``),
checked against the method's parameters and their declared constraints before anything is fitted.

This package holds the group (:func:`main`) and how it reports errors; each command is one module
(``train``, ``evaluate``, …), and what several commands share sits in the ``_``-prefixed modules.
No module here names a method: the defaults and the reference row come from
:mod:`btel.methods.registry`.
"""

from __future__ import annotations

import importlib
import os
import sys
import warnings
from typing import TYPE_CHECKING, Any

import click

from .. import __version__
from ._errors import EXIT_BROKEN_PIPE
from ._options import EXIT_FAILURE, EXIT_INTERRUPTED, EXIT_SOME_ROWS_FAILED, EXIT_USAGE

if TYPE_CHECKING:  # pragma: no cover - each command's module is imported when that command runs
    from ._gallery import show_cmd
    from .demo import demo
    from .evaluate import evaluate_cmd
    from .experiment import experiment
    from .extract import extract
    from .info import info
    from .localize import localize
    from .methods import methods_cmd
    from .report import report
    from .train import train

__all__ = ["main", "EXIT_FAILURE", "EXIT_USAGE", "EXIT_INTERRUPTED", "EXIT_SOME_ROWS_FAILED"]

def _show_warning(message: Any, category: type, filename: str, lineno: int, file: Any = None,
                  line: str | None = None) -> None:
    """Warnings as one line on stderr, without the source location a user cannot act on."""
    click.echo(f"Warning: {message}", err=True)


#: Command name → (module, function). A command's module is imported when it runs (``btel localize`` reads
#: no training code) or when ``--help`` lists it.
_COMMANDS = {"demo": ("demo", "demo"), "extract": ("extract", "extract"), "train": ("train", "train"),
             "localize": ("localize", "localize"), "evaluate": ("evaluate", "evaluate_cmd"),
             "methods": ("methods", "methods_cmd"), "info": ("info", "info"),
             "experiment": ("experiment", "experiment"), "report": ("report", "report"),
             "show": ("_gallery", "show_cmd")}


class _Group(click.Group):
    """Errors as one-line messages and exit statuses (module docstring); a command imported when used."""

    def list_commands(self, ctx: click.Context) -> list[str]:
        return sorted({*_COMMANDS, *self.commands})

    def get_command(self, ctx: click.Context, cmd_name: str) -> click.Command | None:
        if cmd_name in _COMMANDS and cmd_name not in self.commands:
            module, name = _COMMANDS[cmd_name]
            self.add_command(getattr(importlib.import_module(f".{module}", __name__), name), cmd_name)
        return self.commands.get(cmd_name)

    def invoke(self, ctx: click.Context) -> Any:
        from ._errors import STDOUT_CLOSED, exit_for_interrupt
        from ._signals import ending_on_signals

        if not os.environ.get("BTEL_DEBUG"):
            warnings.showwarning = _show_warning
        try:
            from ..core.limits import memory_limit

            memory_limit()  # a malformed BTEL_MEMORY_LIMIT is named as itself, not as a fault of some input
            # SIGTERM (timeout, SLURM, docker stop) ends a command as Ctrl-C does, even inside a long C call.
            with ending_on_signals():
                result = super().invoke(ctx)
        except (click.ClickException, click.exceptions.Exit, click.exceptions.Abort):
            raise
        except KeyboardInterrupt as exc:
            status = exit_for_interrupt(exc)
            click.echo("Interrupted." if status == EXIT_INTERRUPTED else "Terminated (SIGTERM).", err=True)
            raise click.exceptions.Exit(status) from None
        except BrokenPipeError:
            # The reader of stdout went away (`btel ... | head`): stop quietly, as a Unix tool killed by
            # SIGPIPE does, and point stdout at /dev/null so the interpreter's last flush cannot fail too.
            try:
                os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
            except (AttributeError, ValueError, OSError):  # a stdout with no descriptor (a test runner's)
                pass
            raise click.exceptions.Exit(EXIT_BROKEN_PIPE) from None
        except Exception as exc:
            from ..exceptions import BTELError
            from ._errors import LIBRARY_ERRORS, InputError, cli_message, exit_status

            if not isinstance(exc, (BTELError, *LIBRARY_ERRORS)) or os.environ.get("BTEL_DEBUG"):
                raise
            message = str(exc) or type(exc).__name__
            if not isinstance(exc, (BTELError, OSError, ValueError)):  # a library's error: say which
                message = f"{type(exc).__name__}: {message}"
            message = cli_message(message)
            error = (InputError if exit_status(exc) == EXIT_USAGE else click.ClickException)(
                message.splitlines()[0] if len(message) > 2000 else message)
            raise error from exc
        if ctx.meta.get(STDOUT_CLOSED):  # a run that went on after its reader left: 141, as `btel train`
            raise click.exceptions.Exit(EXIT_BROKEN_PIPE)
        return result


@click.group(cls=_Group, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, prog_name="btel")
def main() -> None:
    """btel: visual place recognition under a storage budget (binary tree encoding, BTEL).

    \b
    Typical path:
      btel extract IMAGES_DIR -o db.npy --descriptor hog
      btel train db.npy -o map.btel.npz --budget 500KB
      btel localize map.btel.npz queries.npy -o predictions.csv
      btel evaluate --db db.npy --queries queries.npy \\
          --methods auto,btel-codes,lsh,pq --budget 64KB --out runs/x
    Try `btel demo` first: it needs no data.
    """


if __name__ == "__main__":  # pragma: no cover
    main()
