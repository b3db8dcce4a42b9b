"""``btel methods``: the registered methods, one line each, and what ``--param`` can set."""

from __future__ import annotations

import click


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
            from ._params import parameter_lines

            runtime = set(getattr(model, "_runtime_params", ()))
            for line in parameter_lines(model, runtime=runtime):
                click.echo(" " * (width + 4) + line)
