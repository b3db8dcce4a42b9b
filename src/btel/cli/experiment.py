"""``btel experiment``: run one of the paper's experiments on Nordland."""

from __future__ import annotations

import click

from ._options import _NO_PROGRESS_HELP, _command_line


@click.command()
@click.argument("name", metavar="NAME")
@click.option("--data", "data_root", type=click.Path(file_okay=False), default=None,
              help="Folder with summer/ and winter/ (default $BTEL_SHARED_DATA/nordland64, else "
                   "../shared/data/nordland64).")
@click.option("-o", "--out", "--output", "out_dir", type=click.Path(file_okay=False), default="runs/experiments",
              show_default=True,
              help="Runs folder; results go to OUT/NAME/.")
@click.option("--cache", "cache_dir", type=click.Path(file_okay=False), default=None,
              help="Descriptor cache (default OUT/cache).")
@click.option("--quick", is_flag=True, help="Small version (first 300 frames, few points): for tests and smoke runs.")
@click.option("--delta", type=int, default=None, metavar="W",
              help="Run every method with delta descriptors over W frames (front end; results go to "
                   "OUT/NAME-delta-W/ so they sit beside the default runs).")
@click.option("-j", "--jobs", type=click.IntRange(min=1), default=1, show_default=True, metavar="N",
              help="frontier: run N of its maps at once, one process and one thread each (about 1/N "
                   "of the wall time on N free cores).")
@click.option("--resume", is_flag=True,
              help="frontier: take up an interrupted run in OUT/frontier/ — the rows of its rows.jsonl measured "
                   "by the same btel on the same data are kept, the others run.")
@click.option("--overwrite", is_flag=True, help="Replace an earlier run's results in OUT/NAME/ (refused otherwise).")
@click.option("--no-progress", is_flag=True, help=_NO_PROGRESS_HELP)
def experiment(name: str, data_root: str | None, out_dir: str, cache_dir: str | None, quick: bool,
               delta: int | None, jobs: int, resume: bool, overwrite: bool, no_progress: bool) -> None:
    """Run one of the paper's experiments on Nordland (or 'all').

    \b
    NAME: accuracy | vs-n | vs-budget | feature-ratio | regions | sequence-filter | beyond |
          front-ends | codes | frontier | all
    Every method runs with its default front end (rows L2-normalised; SeqSLAM none) unless --delta.
    Each writes results.csv, results.json and PNG plots into OUT/NAME/; `btel report` turns the
    latest runs into docs/results.md.
    """
    from ..experiments import (EXPERIMENTS, PARALLEL, RESUMABLE, check_output, check_request, describe_row,
                               output_folder, run_experiment)

    from ..experiments._common import experiment_jobs

    experiment_jobs()  # a malformed BTEL_EXPERIMENT_JOBS is named before any work, not after the first fits
    names = list(EXPERIMENTS) if name == "all" else [name]
    # 'all' applies --jobs and --resume where they apply; one experiment named is refused them otherwise.
    options = {n: {"front_end": {"delta": delta} if delta else None,
                   "jobs": jobs if n in PARALLEL or name != "all" else 1,
                   "resume": resume if n in RESUMABLE or name != "all" else False} for n in names}
    for n in names:  # every refusal before the first line is printed or the first experiment runs
        check_request(n, **options[n])
        check_output(output_folder(n, out_dir, options[n]["front_end"]), overwrite=overwrite,
                     resume=options[n]["resume"])
    for n in names:
        click.echo(f"experiment {n}{' (quick)' if quick else ''} …")
        run = run_experiment(n, data_root=data_root, out_dir=out_dir, cache_dir=cache_dir, quick=quick,
                             command=_command_line(), overwrite=overwrite, progress=not no_progress,
                             **options[n])
        for row in run.rows:
            click.echo("  " + describe_row(row))
        click.echo(f"  written to {run.out_dir}")
