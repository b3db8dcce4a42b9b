"""``btel methods``: the registered methods, one line each, and what ``--param`` can set."""

from __future__ import annotations

from typing import Any

import click

from ._params import _param_text


@click.command(name="methods")
@click.option("--params", "show_params", is_flag=True,
              help="Also list each method's parameters: NAME=DEFAULT: allowed values — meaning ([runtime]: how it "
                   "runs, not what it computes; not saved with a model).")
def methods_cmd(show_params: bool) -> None:
    """List the registered methods, one line each (and, with --params, what --param can set).

    † marks methods that use the query sequence.
    """
    from ..methods.registry import DESCRIPTIONS, METHODS, make_method

    width = max(len(n) for n in METHODS)
    for name in METHODS:
        model = make_method(name)
        mark = " †" if model.uses_query_sequence else ""
        click.echo(f"{name:<{width}}  {DESCRIPTIONS.get(name, '')}{mark}")
        if show_params:
            for line in parameter_lines(model):
                click.echo(" " * (width + 4) + line)


def parameter_lines(model: Any) -> list[str]:
    """One line per parameter of ``model``: ``name=default [runtime]: allowed values — meaning``."""
    from ..core.paramdocs import parameter_table

    return [f"{name}={_param_text(default)}{' [runtime]' if runtime else ''}: {allowed}"
            + (f" — {meaning}" if meaning else "")
            for name, default, allowed, meaning, runtime in parameter_table(model)]
