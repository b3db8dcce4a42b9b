"""``btel report``: docs/results.md and docs/results.json from the latest experiment runs."""

from __future__ import annotations

import click


@click.command()
@click.option("--runs", "runs_dir", type=click.Path(file_okay=False), default="runs/experiments", show_default=True)
@click.option("--docs", "docs_dir", type=click.Path(file_okay=False), default="docs", show_default=True)
def report(runs_dir: str, docs_dir: str) -> None:
    """Write docs/results.md and docs/results.json (plus figures) from the latest experiment runs."""
    from ..experiments.report import write_report

    path = write_report(runs_dir, docs_dir)
    click.echo(f"written {path} and {path.with_suffix('.json')}")
