"""``btel evaluate``: localize queries with each method (fitted on a map or saved), write a run folder."""

from __future__ import annotations

from pathlib import Path

import click

from ..methods.roles import DEFAULT_METHOD
from ._inputs import (_load_matrix, calibrate_evaluation, check_evaluate_calibration, check_utm_options,
                      read_ground_truth)
from ._jobs import _fit_jobs, _run_jobs
from ._options import (EXIT_SOME_ROWS_FAILED, _BUDGET_HELP, _DELTA_HELP, _N_JOBS_HELP, _NO_PROGRESS_HELP,
                       _ORDER_HELP, _PARAMS_HELP, _REFERENCE_HELP, _TIMING_THREADS_HELP, _budgets, _int_list,
                       _runtime_shortcuts, _split, calibration_options)

_GT_HELP = ("Which map places are correct for each query. Default: frame-aligned (query j is place j). "
            "Files: .npz (query_places; indptr+indices; utmDb+utmQ+posDistThr), .npy (true places, or "
            "VPR-Bench's ground_truth_new.npy), .mat (NetVLAD dbStruct), .csv (query,positive). 'utm': "
            "positives within --positive-dist-threshold metres of the UTM in the image names.")
_PAIRS_HELP = ("Also write an hloc retrieval pairs file (query_name db_name per line, each query's top K of "
               "the largest --k); with several methods one file each, FILE-<method>.txt (file-safe names).")
FILE, FOLDER = dict(type=click.Path(dir_okay=False), default=None), dict(type=click.Path(file_okay=False))


@click.command(name="evaluate")
@click.option("--db", **FILE, help="Map descriptors to fit --methods on: .npy, .npz[:KEY], .h5[:PREFIX].")
@click.option("--model", "model_paths", multiple=True, **FILE, help="A saved model to evaluate (repeatable).")
@click.option("--queries", required=True, **FILE, help="Query descriptors (as --db).")
@click.option("--methods", default=DEFAULT_METHOD, show_default=True, help="Method names, comma-separated.")
@click.option("--budget", default=None, help=_BUDGET_HELP)
@click.option("--no-reference", is_flag=True, help=_REFERENCE_HELP)
@click.option("--param", "param_texts", multiple=True, metavar="[METHOD:]NAME=VALUE", help=_PARAMS_HELP)
@click.option("--ground-truth", **FILE, help=_GT_HELP)
@click.option("--positive-dist-threshold", type=float, default=None, metavar="METRES",
              help="With --ground-truth (or --calibrate-truth) utm: the positives' radius (default 25).")
@click.option("--pairs", "pairs_path", **FILE, help=_PAIRS_HELP)
@click.option("--tolerances", default=None, metavar="T,T,…",
              help="recall@t tolerances in frames (default 0,1,2,5,10,20 up to a tenth of the map).")
@click.option("--k", "ks_text", default="1,5,10,20", show_default=True, metavar="K,K,…",
              help="R@K: a correct place among the top K candidates (the metric of explicit positives).")
@click.option("--query-order", type=click.Choice(["route", "independent"]), default="route",
              show_default=True, help=_ORDER_HELP)
@click.option("--out", "out_dir", **FOLDER, default=None, help="Run folder (unless --resume).")
@click.option("--overwrite", is_flag=True, help="Replace the run files in an existing run folder.")
@click.option("--resume", "resume_dir", **FOLDER, default=None, metavar="RUN",
              help="Go on with the interrupted run RUN: its rows done are kept, the others run.")
@click.option("--delta", type=int, default=None, metavar="W", help=_DELTA_HELP)
@click.option("--no-progress", is_flag=True, help=_NO_PROGRESS_HELP)
@click.option("--n-jobs", type=int, default=None, help=_N_JOBS_HELP)
@click.option("--timing-threads", type=click.IntRange(min=0), default=1, show_default=True,
              help=_TIMING_THREADS_HELP)
@calibration_options
@click.pass_context
def evaluate_cmd(ctx: click.Context, db: str | None, model_paths: tuple[str, ...], queries: str,
                 methods: str, budget: str | None, no_reference: bool, param_texts: tuple[str, ...],
                 ground_truth: str | None, positive_dist_threshold: float | None, pairs_path: str | None,
                 tolerances: str | None, ks_text: str, query_order: str, out_dir: str | None, overwrite: bool,
                 resume_dir: str | None, delta: int | None, no_progress: bool, n_jobs: int | None,
                 timing_threads: int, calibrate: str | None, calibrate_truth: str | None,
                 calibrate_tolerance: int | None) -> None:
    """Localize QUERIES with each method; write metrics.json, metrics.csv, predictions and plots to --out.

    Methods are fitted on --db (--methods, --budget, --param) or loaded from --model files; all is checked
    before any fit, and a method that does not fit (or fails) becomes a row with its reason. Exit: 0 all
    ran; 1 some did not, or a failure; 2 usage or input; 130 Ctrl-C. With --calibrate, the methods whose
    fit takes labelled queries (auto) choose on them; metrics.json and calibration.md hold their table.
    """
    from ..evaluation.inputs import common_map_size, run_title, saved_jobs
    from ..evaluation.runs import check_run_folder, read_finished_rows
    from ..exceptions import InvalidParameterError

    front = {"delta": ("--delta", delta)} if delta is not None else {}
    if db is None and (not model_paths or param_texts or front):
        raise click.UsageError("give --db (to fit --methods, --param, --delta); --model files keep theirs.")
    if resume_dir is not None and (overwrite or out_dir not in (None, resume_dir)):
        raise click.UsageError("--resume RUN writes on into RUN: drop --out and --overwrite.")
    if out_dir is None and resume_dir is None:
        raise click.UsageError("give --out RUN_FOLDER (or --resume RUN to go on with an interrupted run).")
    out = Path(out_dir or resume_dir)
    budgets, ks = _budgets(budget) if budget else [None], _int_list(ks_text, "--k", minimum=1)
    tolerance_list = _int_list(tolerances, "--tolerances", minimum=0) if tolerances is not None else None
    jobs = [] if db is None else _fit_jobs(_split(methods), budgets, param_texts, reference=not no_reference,
                                           shortcuts={**front, **_runtime_shortcuts(no_progress, n_jobs)})
    check_evaluate_calibration(jobs, db, calibrate, calibrate_truth, calibrate_tolerance)
    try:
        finished = None if resume_dir is None else read_finished_rows(resume_dir, queries, echo=click.echo)
    except InvalidParameterError as exc:
        raise click.UsageError(f"--resume: {exc}") from None
    if finished is None:
        check_run_folder(out, overwrite)
    Q = _load_matrix(queries, "query descriptors")
    X = _load_matrix(db, "map descriptors") if db is not None else None
    saved = saved_jobs(model_paths, Q.shape[1])
    n_map = common_map_size(X, Q, saved)
    check_utm_options(ground_truth, calibrate_truth, db, positive_dist_threshold)
    gt, truth = read_ground_truth(ground_truth, "--ground-truth", n_queries=Q.shape[0], n_map=n_map, db=db,
                                  queries=queries, threshold=positive_dist_threshold)
    if tolerance_list is not None and not gt.uses_tolerance:
        raise click.UsageError("--tolerances needs one true place per query; --ground-truth lists explicit "
                               "positives, which have no tolerance. Use --k (R@K) instead.")
    title = run_title(Path(db or queries).name.split(".")[0], n_map, Q.shape[0], budgets, truth,
                      saved=bool(saved), fitted=bool(jobs))
    click.echo(f"map: N = {n_map} places; queries: {Q.shape[0]} × {Q.shape[1]}; "
               f"ground truth: {truth['rule']} ({truth['source']})")
    from ._names import input_names, plan_pairs
    names = input_names(db, queries, n_map, Q.shape[0])
    pairs = plan_pairs(pairs_path, [j.name for j in saved + jobs], names, (Q.shape[0], n_map), queries, db,
                       overwrite)
    extra = {"db": str(Path(db).resolve()) if db else None, "models": list(model_paths), "budget": budgets,
             "queries": str(Path(queries).resolve()), "query_order": query_order}
    if calibrate:
        extra["calibration"] = calibrate_evaluation(saved + jobs, Q, db, calibrate, calibrate_truth,
                                                    calibrate_tolerance, n_map, positive_dist_threshold)
    if _run_jobs(saved + jobs, X, Q, out=out, progress=not no_progress, extra=extra, pairs=pairs,
                 ground_truth=gt, truth=truth, title=title, names=names, tolerances=tolerance_list, ks=ks,
                 overwrite=overwrite, queries_are_route=query_order == "route", finished=finished,
                 timing_threads=timing_threads or None):
        ctx.exit(EXIT_SOME_ROWS_FAILED)
