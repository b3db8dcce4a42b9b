"""``btel report``: docs/results.md and docs/results.json from the latest experiment runs."""

from __future__ import annotations

import click


@click.command()
@click.option("--runs", "runs_dir", type=click.Path(file_okay=False), default="runs/experiments", show_default=True,
              help="The folder `btel experiment` wrote (one sub-folder per experiment, each with results.json).")
@click.option("--docs", "docs_dir", type=click.Path(file_okay=False), default="docs", show_default=True,
              help="Where results.md, results.json and figures/ go (the documentation site's folder).")
@click.option("--overwrite", is_flag=True,
              help="Replace a results.md or results.json that btel report did not write, or a page whose sections "
                   "these runs would drop or downgrade to quick mode (both kept otherwise).")
def report(runs_dir: str, docs_dir: str, overwrite: bool) -> None:
    """Write docs/results.md and docs/results.json (plus figures) from the latest `btel experiment` runs.

    It reads experiment runs only; an evaluation's run folder (`btel evaluate --out RUN`) already holds its
    tables (metrics.csv) and plots.
    """
    from ..experiments.report import write_report

    path = write_report(runs_dir, docs_dir, overwrite=overwrite)
    click.echo(f"written {path} and {path.with_suffix('.json')}")
