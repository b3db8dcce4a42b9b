"""``btel evaluate``: localize queries with each method (fitted on a map or saved) and write a run folder."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import click

from ..methods.roles import DEFAULT_METHOD
from ._errors import InputError
from ._inputs import _load_matrix
from ._jobs import _fit_jobs, _run_jobs
from ._options import (EXIT_SOME_ROWS_FAILED, _BUDGET_HELP, _DELTA_HELP, _N_JOBS_HELP, _NO_PROGRESS_HELP, _ORDER_HELP,
                       _PARAMS_HELP, _REFERENCE_HELP, _TIMING_THREADS_HELP, _budget_text, _budgets, _int_list,
                       _runtime_shortcuts, _split)
from ._outputs import refuse_existing


@click.command(name="evaluate")
@click.option("--db", type=click.Path(dir_okay=False), default=None,
              help="Map descriptors to fit --methods on: .npy, .npz (FILE.npz:KEY names the array), or hloc global "
                   "features FILE.h5 (FILE.h5:PREFIX keeps images whose name starts with PREFIX). Row i = place i.")
@click.option("--model", "model_paths", multiple=True, type=click.Path(dir_okay=False),
              help="A saved model to evaluate instead of fitting (repeatable).")
@click.option("--queries", required=True, type=click.Path(dir_okay=False),
              help="Query descriptors, one query per row (same formats as --db).")
@click.option("--methods", default=DEFAULT_METHOD, show_default=True, help="Comma-separated method names (with --db).")
@click.option("--budget", default=None, help=_BUDGET_HELP)
@click.option("--no-reference", is_flag=True, help=_REFERENCE_HELP)
@click.option("--param", "param_texts", multiple=True, metavar="[METHOD:]NAME=VALUE", help=_PARAMS_HELP)
@click.option("--ground-truth", type=click.Path(dir_okay=False), default=None,
              help="Which map places are correct for each query. Default: frame-aligned (query j is place j). "
                   "Files: .npz (query_places; indptr+indices positives; utmDb+utmQ+posDistThr), .npy (1-D true "
                   "places, or VPR-Bench's ground_truth_new.npy object array), .mat (NetVLAD dbStruct), "
                   ".csv (header query,positive: one pair per line). 'utm': VPR-methods-evaluation data (images "
                   "named @utm_east@utm_north@…, described with btel extract DATASET/database and DATASET/queries): "
                   "positives within --positive-dist-threshold metres.")
@click.option("--positive-dist-threshold", type=float, default=None, metavar="METRES",
              help="With --ground-truth utm: map images within this many metres of a query are its positives "
                   "(default 25, VPR-methods-evaluation's).")
@click.option("--pairs", "pairs_path", type=click.Path(dir_okay=False), default=None,
              help="Also write an hloc retrieval pairs file (query_name db_name per line, each query's top K of the "
                   "largest --k, best first); with several methods one file each, FILE-<method>.txt. Names come "
                   "from the inputs (btel extract's .json, hloc .h5), else row numbers.")
@click.option("--tolerances", default=None, metavar="T,T,…",
              help="recall@t tolerances in frames (one true place per query only). Default: 0,1,2,5,10,20 up "
                   "to a tenth of the map (0,1,2,5,10 on a 111-place route).")
@click.option("--k", "ks_text", default="1,5,10,20", show_default=True, metavar="K,K,…",
              help="R@K: a correct place among the top K ranked candidates (every method ranks; R@1 is the point "
                   "prediction). With explicit positives R@K is the only metric.")
@click.option("--query-order", type=click.Choice(["route", "independent"]), default="route", show_default=True,
              help=_ORDER_HELP)
@click.option("--out", "out_dir", type=click.Path(file_okay=False), default=None,
              help="Run folder (required unless --resume).")
@click.option("--overwrite", is_flag=True, help="Replace the run files in an existing run folder.")
@click.option("--resume", "resume_dir", type=click.Path(file_okay=False), default=None, metavar="RUN",
              help="Go on with the run folder RUN (interrupted with Ctrl-C): the rows already done (status ok) are "
                   "kept and not run again, the others run. Give the same --db/--model/--queries and options.")
@click.option("--normalize", type=click.Choice(["none", "l2", "power"]), default=None,
              help="Every method's front-end normalisation (default l2; SeqSLAM none). Same as --param normalize=…")
@click.option("--whiten", type=int, default=None, metavar="P",
              help="Every method: PCA-whiten to P dimensions (counted in its bytes). Same as --param whiten=P.")
@click.option("--delta", type=int, default=None, metavar="W", help=_DELTA_HELP)
@click.option("--no-progress", is_flag=True, help=_NO_PROGRESS_HELP)
@click.option("--n-jobs", type=int, default=None, help=_N_JOBS_HELP)
@click.option("--timing-threads", type=click.IntRange(min=0), default=1, show_default=True, help=_TIMING_THREADS_HELP)
@click.pass_context
def evaluate_cmd(ctx: click.Context, db: str | None, model_paths: tuple[str, ...], queries: str, methods: str,
                 budget: str | None, no_reference: bool, param_texts: tuple[str, ...], ground_truth: str | None,
                 positive_dist_threshold: float | None, pairs_path: str | None, tolerances: str | None, ks_text: str, query_order: str, out_dir: str | None, overwrite: bool,
                 resume_dir: str | None,
                 normalize: str | None, whiten: int | None, delta: int | None, no_progress: bool,
                 n_jobs: int | None, timing_threads: int) -> None:
    """Localize QUERIES with each method and write metrics.json, metrics.csv, predictions and plots to --out.

    Methods are fitted on --db (by name, --methods, each with --budget and its --param values), or
    loaded from saved --model files (which keep the parameters they were fitted with).

    \b
    Before anything is fitted: the run folder, the ground truth against the query and map
    counts, and every method against its budget are checked, and every method that cannot run
    is listed at once. A method that does not fit (or fails) becomes a row with its status and
    reason; every other row is kept. metrics.json / metrics.csv are rewritten as each method
    finishes, so a crash or Ctrl-C keeps what is done.
    Exit status: 0 every row ran; 1 the run finished but some row did not fit or failed (or a
    failure while running); 2 bad usage or input; 130 Ctrl-C.

    \b
    Metrics: recall@t = the point prediction within t frames of the true place (frame-aligned
    or one-true-place ground truth); R@K = a correct place among the top K candidates.
    Methods marked † use the query sequence (SeqSLAM, delta front ends): not comparable with
    single-frame methods.
    """
    from .. import load
    from ..datasets import GroundTruth
    from ..evaluation.measure import Job, check_ground_truth
    from ..evaluation.runs import check_run_folder

    if db is None and not model_paths:
        raise click.UsageError("give --db (to fit --methods) or at least one --model.")
    if resume_dir is not None and out_dir is not None and Path(out_dir) != Path(resume_dir):
        raise click.UsageError("--resume RUN writes into RUN; drop --out (or give the same folder).")
    if resume_dir is not None and overwrite:
        raise click.UsageError("--resume keeps the rows of RUN; --overwrite would replace them. Give one.")
    if out_dir is None and resume_dir is None:
        raise click.UsageError("give --out RUN_FOLDER (or --resume RUN to go on with an interrupted run).")
    out_dir = out_dir or resume_dir
    if param_texts and db is None:
        raise click.UsageError("--param sets parameters of the methods fitted on --db; saved --model files keep theirs.")
    budgets = _budgets(budget) if budget else [None]
    ks = _int_list(ks_text, "--k", minimum=1)
    tolerance_list = _int_list(tolerances, "--tolerances", minimum=0) if tolerances is not None else None
    front = {name: (f"--{name}", value) for name, value in
             (("normalize", normalize), ("whiten", whiten), ("delta", delta)) if value is not None}
    if front and db is None:
        raise click.UsageError("--normalize/--whiten/--delta set the front end of methods fitted on --db; saved "
                               "--model files keep theirs.")
    jobs = _fit_jobs(_split(methods), budgets, param_texts, reference=not no_reference,
                     shortcuts={**front, **_runtime_shortcuts(no_progress, n_jobs)}) \
        if db is not None else []
    # Cheap checks first, so that nothing is fitted for a run that cannot be written or scored.
    finished = _finished_rows(resume_dir, queries) if resume_dir is not None else None
    if finished is None:
        check_run_folder(Path(out_dir), overwrite)
    Q = _load_matrix(queries, "query descriptors")
    X = None
    if db is not None:
        X = _load_matrix(db, "map descriptors")
        if X.shape[1] != Q.shape[1]:
            raise InputError(
                f"--db has {X.shape[1]} dims but --queries has {Q.shape[1]}; describe both with the same descriptor.")
    saved = []
    for path in model_paths:
        model = load(path)
        if model.n_features_in_ != Q.shape[1]:
            raise InputError(f"--model {path} expects {model.n_features_in_}-D descriptors but --queries "
                                       f"has {Q.shape[1]}.")
        saved.append(Job(Path(path).name.split(".")[0], model, fit=False))
    n_maps = {int(j.method.n_places_) for j in saved} | ({X.shape[0]} if X is not None else set())
    if len(n_maps) > 1:
        raise InputError(f"the maps differ in size ({sorted(n_maps)} places): --db and every --model "
                                   "must cover the same map for one ground truth to hold.")
    n_map = n_maps.pop()
    if positive_dist_threshold is not None and ground_truth != "utm":
        raise click.UsageError("--positive-dist-threshold applies with --ground-truth utm (positions in the image "
                               "names); a ground-truth file says its own positives.")
    if positive_dist_threshold is not None and not positive_dist_threshold > 0:
        raise click.UsageError(f"--positive-dist-threshold must be > 0 metres; got {positive_dist_threshold:g}.")
    if ground_truth == "utm":
        from ..datasets.vpr_names import DEFAULT_POSITIVE_DIST_THRESHOLD
        from ._names import utm_ground_truth

        if db is None:
            raise click.UsageError("--ground-truth utm reads the map's image names from --db; give --db.")
        threshold = DEFAULT_POSITIVE_DIST_THRESHOLD if positive_dist_threshold is None else positive_dist_threshold
        given = utm_ground_truth(db, queries, n_map, Q.shape[0], threshold)
    else:
        given = _ground_truth_file(ground_truth, Q.shape[0], n_map) if ground_truth else None
    gt = check_ground_truth(given, Q.shape[0], n_map, option="--ground-truth")
    if tolerance_list is not None and not gt.uses_tolerance:
        raise click.UsageError("--tolerances needs one true place per query; --ground-truth lists explicit "
                               "positives, which have no tolerance. Use --k (R@K) instead.")
    truth = ("frame-aligned" if ground_truth is None else
             f"positives within {threshold:g} m (UTM in the image names)" if ground_truth == "utm" else
             f"{'one true place per query' if gt.uses_tolerance else 'positives'} from {Path(ground_truth).name}")
    dataset = Path(db if db else queries).name.split(".")[0]
    budget_part = (f"budget {_budget_text(budgets)}" if any(budgets) else
                   "saved models" + (" and unbudgeted methods" if jobs else "") if saved else "no budget")
    title = f"{dataset}: N = {n_map}, {Q.shape[0]} queries; {budget_part}; {truth}"
    click.echo(f"map: N = {n_map} places; queries: {Q.shape[0]} × {Q.shape[1]}; ground truth: {truth}")
    from ._names import input_names

    pairs, names = None, input_names(db, queries, n_map, Q.shape[0])
    if pairs_path is not None:
        from ._names import check_pair_names, pairs_paths

        targets = pairs_paths(pairs_path, [j.name for j in saved + jobs])
        for target in targets.values():
            refuse_existing(target, "--pairs", overwrite)
        pairs = (targets, names[0] or [str(i) for i in range(Q.shape[0])], names[1] or [str(i) for i in range(n_map)])
        check_pair_names(*pairs[1:], queries, db)
    failed = _run_jobs(saved + jobs, X, Q, ground_truth=gt, out=Path(out_dir), overwrite=overwrite, title=title,
                       pairs=pairs, names=names,
                       tolerances=tolerance_list, ks=ks, queries_are_route=query_order == "route",
                       progress=not no_progress, finished=finished, timing_threads=timing_threads or None,
                       extra={"db": str(Path(db).resolve()) if db else None, "models": list(model_paths),
                              "queries": str(Path(queries).resolve()), "budget": budgets,
                              "ground_truth": str(Path(ground_truth).resolve()) if ground_truth else "frame-aligned",
                              "query_order": query_order})
    if failed:
        ctx.exit(EXIT_SOME_ROWS_FAILED)


def _ground_truth_file(path: str, n_queries: int, n_map: int) -> Any:
    """``--ground-truth FILE``, its counts checked against the descriptors before any positive is computed."""
    from ..datasets import GroundTruth
    from ..exceptions import InvalidParameterError

    try:
        return GroundTruth.from_file(path, n_queries=n_queries, n_map=n_map)
    except InvalidParameterError as exc:
        raise InputError(f"--ground-truth: {exc}") from None


def _finished_rows(run: str, queries: str) -> list[Any]:
    """The rows of the run folder ``run`` to keep (``--resume``), after checking it ran on ``queries``."""
    from ..evaluation.runs import read_unfinished_run

    meta, rows = read_unfinished_run(run)
    before = (meta.get("extra") or {}).get("queries")
    if before is not None and before != str(Path(queries).resolve()):
        raise click.UsageError(f"--resume {run}: that run localized {before}, not {queries}; give the same "
                               "--queries (and --db/--model, options) as the interrupted run.")
    done = [r for r in rows if r.ok]
    click.echo(f"resuming {run}: {len(done)} of {len(rows)} rows done ({', '.join(r.name for r in done) or 'none'}); "
               "the others run now")
    return done
