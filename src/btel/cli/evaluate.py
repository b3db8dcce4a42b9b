"""``btel evaluate``: localize queries with each method (fitted on a map or saved), write a run folder."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import click
from click.core import ParameterSource

from ..methods.roles import DEFAULT_METHOD
from ._errors import InputError
from ._inputs import (_load_map, _load_matrix, calibrate_evaluation, check_evaluate_calibration, check_utm_options,
                      read_ground_truth, refuse_matrix_as_model)
from ._jobs import _echo_while_running, _fit_jobs, _run_jobs
from ._options import (timing_threads_option,
                       EXIT_SOME_ROWS_FAILED, _BUDGET_HELP, _DELTA_HELP, _N_JOBS_HELP, _NO_PROGRESS_HELP,
                       _ORDER_HELP, _PARAMS_HELP, _REFERENCE_HELP, _TIMING_THREADS_HELP, _budgets, _int_list,
                       _runtime_shortcuts, _split, calibration_options)

_GT_HELP = ("Which map places are correct for each query. Default: frame-aligned (query j is place j). "
            "Files: .npz (query_places; indptr+indices; utmDb+utmQ+posDistThr), .npy (true places, or "
            "VPR-Bench's ground_truth_new.npy), .mat (NetVLAD dbStruct), .csv (query,positive). 'utm': "
            "positives within --positive-dist-threshold metres of the UTM in the image names.")
_PAIRS_HELP = ("Also write an hloc retrieval pairs file (query_name db_name per line, each query's top K of "
               "the largest --k); with several methods one file each, FILE-<method>.txt (file-safe names).")
FILE, FOLDER = dict(type=click.Path(dir_okay=False), default=None), dict(type=click.Path(file_okay=False))


#: The options that shape a run's rows (parameter → flag): recorded in metrics.json (``"options"``, by flag) so that
#: ``--resume RUN`` alone goes on with them. Runtime flags (--n-jobs, --no-progress) and --pairs (a file
#: written after the run) change no row, so a resume may give them anew.
_RECORDED = {"db": "--db", "model_paths": "--model", "queries": "--queries", "methods": "--methods",
             "budget": "--budget", "no_reference": "--no-reference", "param_texts": "--param",
             "ground_truth": "--ground-truth", "positive_dist_threshold": "--positive-dist-threshold",
             "tolerances": "--tolerances", "ks_text": "--k", "query_order": "--query-order", "delta": "--delta",
             "timing_threads": "--timing-threads", "calibrate": "--calibrate",
             "calibrate_truth": "--calibrate-truth", "calibrate_tolerance": "--calibrate-tolerance"}


def _path(text: str | None) -> str | None:
    """An input path as recorded: absolute, so that a resume from another folder names the same file
    (``utm``, a ground-truth keyword, stays as it is)."""
    return text if text in (None, "utm") else str(Path(text).resolve())


def _canonical(o: dict[str, Any]) -> dict[str, Any]:
    """The row-shaping options ``o`` as JSON values: paths absolute, lists parsed and checked (usage errors)."""
    return {**o, "db": _path(o["db"]), "model_paths": [_path(m) for m in o["model_paths"]],
            "queries": _path(o["queries"]), "methods": _split(",".join(o["methods"])),
            "budget": _budgets(",".join(o["budget"])) if o["budget"] else [None],
            "param_texts": list(o["param_texts"]), "ground_truth": _path(o["ground_truth"]),
            "tolerances": None if o["tolerances"] is None else _int_list(o["tolerances"], "--tolerances", minimum=0),
            "ks_text": _int_list(o["ks_text"], "--k", minimum=1), "calibrate": _path(o["calibrate"]),
            "calibrate_truth": _path(o["calibrate_truth"])}


def _compared(name: str, value: Any) -> Any:
    """An option's value as a resume compares it: budgets in bytes (``64KB`` is ``64000``), the rest as written."""
    if name != "budget" or not isinstance(value, list):
        return value
    from ..core.storage import parse_budget

    return [None if b is None else parse_budget(b) for b in value]


def _shown(value: Any) -> str:
    """An option's value as the command line writes it (``8KB,32KB``; ``none`` when not given)."""
    return "none" if value in (None, [None]) else ",".join(map(str, value)) if isinstance(value, list) else str(value)


def _resumed_options(ctx: click.Context, given: dict[str, Any], extra: dict[str, Any], run: str) -> dict[str, Any]:
    """The options of the run being resumed: those its metadata ``extra`` recorded, checked against those
    given beside --resume (a differing one is a usage error naming each).

    A run folder written before btel recorded its options keeps only its inputs, budgets and query order:
    those are used, and --methods (not recorded there) must be given again.
    """
    explicit = {name for name in _RECORDED if _given(ctx, name)}
    if "options" in extra:
        if not isinstance(extra["options"], dict):
            raise _damaged(run, "run.extra.options", extra["options"], "it must be an object of flag → value")
        recorded = {name: extra["options"][flag] for name, flag in _RECORDED.items() if flag in extra["options"]}
    elif "methods" not in explicit:
        raise click.UsageError(f"--resume: {run} was written by an older btel that did not record its options; "
                               "give --methods again (and every other option of the interrupted run).")
    else:
        recorded = {name: extra[name] for name in ("db", "queries", "budget", "query_order") if name in extra}
    recorded = {name: _recorded_value(ctx, run, name, value) for name, value in recorded.items()}
    differ = [name for name in _RECORDED if name in explicit and name in recorded
              and _compared(name, recorded[name]) != _compared(name, given[name])]
    if differ:
        flags = [_RECORDED[name] for name in differ]
        was = ", ".join(f"{flag} {_shown(recorded[name])}" for flag, name in zip(flags, differ))
        got = ", ".join((f"{flag} " if len(differ) > 1 else "") + _shown(given[name])
                        for flag, name in zip(flags, differ))
        drop = " and ".join(filter(None, [", ".join(flags[:-1]), flags[-1]]))
        raise click.UsageError(f"--resume: this run was started with {was}; got {got}. Start a new run with --out, "
                               f"or drop {drop} to go on with the recorded {'one' if len(differ) == 1 else 'ones'}.")
    return {**given, **recorded}


def _damaged(run: str, field: str, value: Any, why: str) -> InputError:
    """The error for a field of RUN/metrics.json that btel never writes so (exit 2, naming file, field and fix)."""
    return InputError(f"{Path(run) / 'metrics.json'}: {field} holds {json.dumps(value, default=repr)[:80]}, "
                      f"which btel evaluate never writes ({why}): the file was edited or damaged. Run the "
                      "evaluation again without --resume (btel evaluate … --out NEW_RUN).")


def _recorded_value(ctx: click.Context, run: str, name: str, value: Any) -> Any:
    """A recorded option's value, checked as its flag checks it on the command line: the JSON type
    ``_canonical`` writes, then the flag's own click type (choices, ranges) or parser (lists) — a
    hand-edited or damaged metrics.json is refused here, not as a traceback or a failed row later."""
    param = next(p for p in ctx.command.params if p.name == name)
    flag = _RECORDED[name]

    def refuse(why: str) -> InputError:
        return _damaged(run, f"option {flag}", value, why)

    if value is None and param.default is None and not param.multiple:
        return None  # an option left at its default None is recorded as null
    try:
        if name in ("ks_text", "tolerances"):  # recorded as the sorted list of ints _int_list made
            if not isinstance(value, list) or not all(type(v) is int for v in value):
                raise refuse("it must be a list of integers")
            return _int_list(",".join(map(str, value)), flag, minimum=1 if name == "ks_text" else 0)
        if param.multiple:
            if name == "budget" and value == [None]:  # no --budget: recorded as [null]
                return value
            if not isinstance(value, list) or not all(isinstance(v, str) for v in value):
                raise refuse("it must be a list of strings")
            texts = [param.type.convert(v, param, ctx) for v in value]
            return (_split(",".join(texts)) if name == "methods" else _budgets(",".join(texts))
                    if name == "budget" else texts)
        # One JSON type per click type (a bool is no int, "3" no number): then the flag's own checks.
        kind, what = {"integer": (int, "an integer"), "integer range": (int, "an integer"),
                      "float": ((int, float), "a number"), "boolean": (bool, "true or false")}.get(
            param.type.name, (str, "a string"))
        if not isinstance(value, kind) or (kind is not bool and isinstance(value, bool)):
            raise refuse(f"it must be {what}")
        return param.type.convert(value, param, ctx)
    except (click.BadParameter, click.UsageError) as exc:
        raise refuse(exc.format_message().rstrip(".")) from None


def _given(ctx: click.Context, name: str) -> bool:
    """The option ``name`` was given (on the command line), not left at its default."""
    return ctx.get_parameter_source(name) not in (None, ParameterSource.DEFAULT, ParameterSource.DEFAULT_MAP)


def _read_resumed(ctx: click.Context, given: dict[str, Any],
                  run: str) -> tuple[dict[str, Any], list[Any], dict[str, Any] | None] | None:
    """The options, rows and input fingerprints (None: not recorded) of the run folder ``run`` to go on
    with; None when that run is complete."""
    from ..evaluation.resume import read_unfinished_run
    from ..exceptions import DataNotFoundError, InvalidParameterError

    try:
        meta, rows = read_unfinished_run(run)
    except (DataNotFoundError, InvalidParameterError) as exc:
        raise click.UsageError(f"--resume: {exc}") from None
    extra = meta.get("extra", {})
    if not isinstance(extra, dict):  # else it would read as an older btel's run, asking for --methods
        raise _damaged(run, "run.extra", extra, "it must be an object")
    if extra.get("data") == "synthetic_route":  # its map is generated, not read: nothing to give --resume
        raise click.UsageError(f"--resume: {run} is a `btel demo` run, which is not resumed (it regenerates its "
                               f"route in seconds); run `btel demo --out {run} --overwrite` with the same options "
                               "again.")
    if meta.get("complete"):
        # An option that differs from the run's is refused here too: "nothing to resume" must not read as if
        # a new --budget had been applied.
        _resumed_options(ctx, given, extra, run)
        return None
    recorded = extra.get("inputs")
    return _resumed_options(ctx, given, extra, run), rows, recorded if isinstance(recorded, dict) else None


def _check_inputs_unchanged(run: str, recorded: dict[str, Any] | None, current: dict[str, Any]) -> None:
    """Refuse to resume on inputs whose bytes changed since the run started: the new rows would be
    measured on other data than the rows done (``btel.evaluation.resume``)."""
    from ..evaluation.resume import changed_inputs

    if recorded is None:
        _echo_while_running(f"note: {run} was started by a btel that did not fingerprint its inputs; that they are "
                            "unchanged is not checked.", err=True)
        return
    changed = changed_inputs(recorded, current)
    if changed:
        raise click.UsageError(
            f"--resume: {', '.join(changed)} changed since {run} was started (other bytes, or the file is gone): "
            "the rows done were measured on the old data. Restore the inputs, or start a new run with --out.")


@click.command(name="evaluate")
@click.option("--db", type=click.Path(), default=None,
              help="Map descriptors to fit --methods on: .npy, .npz[:KEY], .h5[:PREFIX] or a folder of .npy shards.")
@click.option("--model", "model_paths", multiple=True, **FILE,
              help="A saved model to evaluate (repeatable); its row is named by the file (and by its folders where "
                   "two files share a name).")
@click.option("--queries", **FILE, help="Query descriptors (as --db); required unless --resume.")
@click.option("--methods", multiple=True, default=(DEFAULT_METHOD,), show_default=True,
              help="Method names, comma-separated; repeatable, the lists are joined (--methods a,b --methods c "
                   "is a,b,c).")
@click.option("--budget", multiple=True, help=_BUDGET_HELP + " Repeatable, the lists are joined. Default: none, "
              "every method as large as it needs.")
@click.option("--no-reference", is_flag=True, help=_REFERENCE_HELP)
@click.option("--param", "param_texts", multiple=True, metavar="[METHOD:]NAME=VALUE", help=_PARAMS_HELP)
@click.option("--ground-truth", **FILE, help=_GT_HELP)
@click.option("--positive-dist-threshold", type=float, default=None, metavar="METRES",
              help="With --ground-truth (or --calibrate-truth) utm: the positives' radius (default 25).")
@click.option("--pairs", "pairs_path", **FILE, help=_PAIRS_HELP)
@click.option("--tolerances", default=None, metavar="T,T,…",
              help="recall@t tolerances in frames (default 0,1,2,5,10,20 up to a tenth of the map).")
@click.option("--k", "ks_text", default="1,5,10,20", show_default=True, metavar="K,K,…",
              help="R@K: a correct place among the top K candidates (the metric of explicit positives); each K "
                   "at most the map's number of places (a default K above it is left out, with a note).")
@click.option("--query-order", type=click.Choice(["route", "independent"]), default="route",
              show_default=True, help=_ORDER_HELP)
@click.option("-o", "--out", "--output", "out_dir", **FOLDER, default=None, help="Run folder (unless --resume).")
@click.option("--overwrite", is_flag=True, help="Replace the run files in an existing run folder.")
@click.option("--resume", "resume_dir", **FOLDER, default=None, metavar="RUN",
              help="Go on with the interrupted run RUN with the inputs and options it recorded (give none, or "
                   "the same): its rows done are kept, the others run. A complete RUN is left as it is (exit 0).")
@click.option("--delta", type=int, default=None, metavar="W", help=_DELTA_HELP)
@click.option("--no-progress", is_flag=True, help=_NO_PROGRESS_HELP)
@click.option("--n-jobs", type=int, default=None, help=_N_JOBS_HELP)
@click.option("--timing-threads", type=click.IntRange(min=0), default=1, show_default=True,
              help=_TIMING_THREADS_HELP, callback=timing_threads_option)
@calibration_options
@click.pass_context
def evaluate_cmd(ctx: click.Context, model_paths: tuple[str, ...], methods: tuple[str, ...],
                 budget: tuple[str, ...], param_texts: tuple[str, ...], pairs_path: str | None,
                 out_dir: str | None, overwrite: bool, resume_dir: str | None, no_progress: bool,
                 n_jobs: int | None, **options: Any) -> None:
    """Localize the --queries with each method; write metrics.json, metrics.csv, predictions and plots to --out.

    \b
    Example:
      btel evaluate --db db.npy --queries q.npy --methods auto,lsh,pq --budget 16KB,64KB --out runs/x
      btel evaluate --model a.npz --model b.npz --queries q.npy --ground-truth gt.npy --out runs/y

    Methods are fitted on --db (--methods, --budget, --param) or loaded from --model files; all is checked
    before any fit, and a method that does not fit (or fails) becomes a row with its reason. Exit: 0 all
    ran; 1 some did not, or a failure; 2 usage or input; 130 Ctrl-C, 143 SIGTERM (the finished rows kept:
    --resume goes on); 141 when the reader of its output went away (after the run folder is written).
    With --calibrate, the methods whose fit takes labelled queries (auto) choose on them; metrics.json and
    calibration.md hold their table.

    --resume RUN needs no other option: the run folder records its inputs and every option that shapes
    its rows; an option given beside it that differs from the recorded one is refused (a run never mixes
    rows of two settings). Resuming a complete run says so and exits 0 without fitting anything.
    """
    from ..evaluation.inputs import common_map_size, fitted_on_other_rows, run_title, saved_jobs
    from ..evaluation.resume import check_finished_rows, input_fingerprints
    from ..evaluation.runs import check_run_folder
    from ..exceptions import ModelFileError

    if resume_dir is not None and (overwrite or out_dir not in (None, resume_dir)):
        raise click.UsageError("--resume RUN writes on into RUN: drop --out and --overwrite.")
    if out_dir is None and resume_dir is None:
        raise click.UsageError("give --out RUN_FOLDER (or --resume RUN to go on with an interrupted run).")
    if options["queries"] is None and resume_dir is None:
        raise click.UsageError("give --queries QUERIES (the query descriptors to localize).")
    o = _canonical({**options, "model_paths": model_paths, "methods": methods, "budget": budget,
                    "param_texts": param_texts})
    rows: list[Any] = []
    recorded_inputs = None
    if resume_dir is not None:
        resumed = _read_resumed(ctx, o, resume_dir)
        if resumed is None:
            _echo_while_running(f"{resume_dir} is a complete run: nothing to resume (no method is fitted). "
                                "Start a new run with --out, or --out RUN --overwrite to run it again.")
            return
        o, rows, recorded_inputs = resumed
    db, queries, budgets, ks = o["db"], o["queries"], o["budget"], o["ks_text"]
    front = {"delta": ("--delta", o["delta"])} if o["delta"] is not None else {}
    if db is None and not o["model_paths"]:
        raise click.UsageError("give --db (the map to fit --methods on) or --model files (saved models).")
    jobs = [] if db is None else _fit_jobs(o["methods"], budgets, tuple(o["param_texts"]),
                                           reference=not o["no_reference"],
                                           shortcuts={**front, **_runtime_shortcuts(no_progress, n_jobs)})
    _check_option_pairs(o)  # after the parameters' values are checked, before anything is read or made
    calibrate, calibrate_truth, calibrate_tolerance = o["calibrate"], o["calibrate_truth"], o["calibrate_tolerance"]
    check_evaluate_calibration(jobs, db, calibrate, calibrate_truth, calibrate_tolerance)
    # Without --db nothing is fitted: these options would be silently ignored, so they are refused.
    unused = [flag for flag, on in (("--methods", _given(ctx, "methods")), ("--budget", _given(ctx, "budget")),
                                    ("--param", o["param_texts"]), ("--delta", front)) if on]
    if db is None and unused:
        raise click.UsageError(f"{' and '.join(unused)} without --db: nothing is fitted, and --model files keep "
                               "theirs (method, size and front end are fixed when a model is trained). Drop "
                               f"{' and '.join(unused)}, give --db to fit --methods on, or `btel train` the model "
                               "again with them.")
    if resume_dir is None:
        check_run_folder(Path(out_dir), overwrite)
    out = Path(out_dir or resume_dir)
    Q = _load_matrix(queries, "query descriptors")
    X = None if db is None else _load_map(db) if Path(db).is_dir() else _load_matrix(db, "map descriptors")
    try:
        saved = saved_jobs(o["model_paths"], Q.shape[1], taken=[j.name for j in jobs])
    except ModelFileError:
        for path in o["model_paths"]:  # a descriptor matrix given as --model: say so, not "corrupt"
            refuse_matrix_as_model(path, "--model", "or give this matrix as --db to fit --methods on it")
        raise
    n_map = common_map_size(X, Q, saved)
    _check_delta_window(o, n_map, Q.shape[0])
    for note in fitted_on_other_rows(X, saved):
        _echo_while_running(f"note: {note}; were --db and the --model files made from the same map?")
    ks = _ks_for_map(ks, n_map, _given(ctx, "ks_text"))
    _check_tolerances(o["tolerances"], n_map)
    threshold = o["positive_dist_threshold"]
    check_utm_options(o["ground_truth"], calibrate_truth, db, threshold)
    gt, truth = read_ground_truth(o["ground_truth"], "--ground-truth", n_queries=Q.shape[0], n_map=n_map, db=db,
                                  queries=queries, threshold=threshold)
    if o["tolerances"] is not None and not gt.uses_tolerance:
        raise click.UsageError("--tolerances needs one true place per query; --ground-truth lists explicit "
                               "positives, which have no tolerance. Use --k (R@K) instead.")
    title = run_title(Path(db or queries).name.split(".")[0], n_map, Q.shape[0], budgets, truth,
                      saved=bool(saved), fitted=bool(jobs))
    _echo_while_running(f"map: N = {n_map} places; queries: {Q.shape[0]} × {Q.shape[1]}; "
                        f"ground truth: {truth['rule']} ({truth['source']})")
    if jobs and budgets == [None]:  # btel is about budgets: an unbudgeted comparison is said to be one
        _echo_while_running("note: no --budget: every method is as large as it needs (pq, lsh, … at their "
                            "defaults); give --budget (e.g. --budget 64KB) to compare under a byte budget.")
    from ._names import input_names, plan_pairs
    names = input_names(db, queries, n_map, Q.shape[0])
    pairs = plan_pairs(pairs_path, [j.name for j in saved + jobs], names, (Q.shape[0], n_map), queries, db,
                       overwrite)
    if pairs is not None:
        _warn_unnamed_pairs(pairs[0], names, queries, db)
    extra = {"db": db, "models": o["model_paths"], "budget": budgets, "queries": queries,
             "query_order": o["query_order"], "options": {flag: o[name] for name, flag in _RECORDED.items()},
             "shapes": {"queries": list(Q.shape), "db": None if X is None else list(X.shape)}}
    if calibrate:
        extra["calibration"] = calibrate_evaluation(saved + jobs, Q, db, calibrate, calibrate_truth,
                                                    calibrate_tolerance, n_map, threshold)
    # Fingerprinted once every input has been read and checked: a file that lies about its size (a sparse
    # .npy claiming terabytes, a /proc file) is refused by its reader in a moment, not hashed for hours first.
    extra["inputs"] = input_fingerprints({"--db": db, "--queries": queries, "--model": list(o["model_paths"]),
                                          "--ground-truth": o["ground_truth"], "--calibrate": calibrate,
                                          "--calibrate-truth": calibrate_truth})
    if resume_dir is not None:
        _check_inputs_unchanged(resume_dir, recorded_inputs, extra["inputs"])
    finished = None
    if resume_dir is not None:
        from ..exceptions import InvalidParameterError

        try:  # a safety net under the options' check: no done row is dropped or kept for another setting
            finished = check_finished_rows(resume_dir, rows, saved + jobs, echo=_echo_while_running)
        except InvalidParameterError as exc:
            raise click.UsageError(f"--resume: {exc}") from None
    if _run_jobs(saved + jobs, X, Q, out=out, progress=not no_progress, extra=extra, pairs=pairs,
                 ground_truth=gt, truth=truth, title=title, names=names, tolerances=o["tolerances"], ks=ks,
                 overwrite=overwrite, queries_are_route=o["query_order"] == "route", finished=finished,
                 timing_threads=o["timing_threads"] or None):
        ctx.exit(EXIT_SOME_ROWS_FAILED)


def _ks_for_map(ks: list[int], n_map: int, given: bool) -> list[int]:
    """The K of R@K that a map of ``n_map`` places has: a K given above it is refused (its column would
    vanish without a word); the default's are left out with a note."""
    above = [k for k in ks if k > n_map]
    if above and given:
        raise click.UsageError(f"--k {_shown(above)}: R@K needs K ≤ the map's N = {n_map} places; give --k values "
                               f"up to {n_map}.")
    if above:
        _echo_while_running(f"note: K = {_shown(above)} of the default --k left out: R@K needs K ≤ "
                            f"the map's N = {n_map} places.")
    return [k for k in ks if k <= n_map]


def _check_option_pairs(o: dict[str, Any]) -> None:
    """Usage errors, before anything is read or any folder made, for options that only apply beside another:
    ``--positive-dist-threshold`` without a ``utm`` ground truth, ``--delta`` with independent queries."""
    threshold, gt = o["positive_dist_threshold"], o["ground_truth"]
    if threshold is not None and "utm" not in (gt, o["calibrate_truth"]):
        given = ("the default ground truth is frame-aligned (query j is place j)" if gt is None else
                 "a ground-truth file gives its own positives (a positions file its radius, posDistThr)")
        raise click.UsageError(
            f"--positive-dist-threshold {threshold:g} is the radius of --ground-truth utm (the positives within "
            "that many metres of the UTM positions in the image names): --positive-dist-threshold applies to it "
            f"(and --calibrate-truth utm) only, and {given}. Drop --positive-dist-threshold, or give "
            "--ground-truth utm.")
    delta, flag, given = _delta_given(o)
    if delta is not None and o["query_order"] == "independent":
        raise click.UsageError(
            f"{given} with --query-order independent: delta descriptors are computed over the query "
            "sequence (the mean of the last W frames minus the W before), which independent queries do not "
            f"have, so every row would be refused. Drop {flag}, or give --query-order route if the query rows "
            "are consecutive frames of one traverse.")


def _delta_given(o: dict[str, Any]) -> tuple[Any, str, str]:
    """The delta window asked for (``--delta W`` or an every-method ``--param delta=W``; None if neither), the
    option that gave it and how it was written (``--delta 3`` / ``--param delta=3``)."""
    if o["delta"] is not None:
        return o["delta"], "--delta", f"--delta {o['delta']}"
    delta = _every_method_param(o["param_texts"], "delta")
    return delta, "--param delta", f"--param delta={delta}"


def _check_delta_window(o: dict[str, Any], n_map: int, n_queries: int) -> None:
    """A delta window the map or the queries are too short for, refused before any fit (each row would fail)."""
    delta, flag, given = _delta_given(o)
    shortest = min(n_map, n_queries)
    if isinstance(delta, int) and not isinstance(delta, bool) and delta >= 1 and shortest < 2 * delta:
        which = "map" if n_map <= n_queries else "query traverse"
        fix = f"{flag}{' ' if flag == '--delta' else '='}{max(shortest // 2, 1)}"
        raise click.UsageError(f"{given} needs traverses of at least 2 × {delta} = {2 * delta} frames; the "
                               f"{which} has {shortest}. Give {fix} or less.")


def _every_method_param(param_texts: list[str], name: str) -> Any:
    """The value ``--param NAME=VALUE`` (no METHOD: prefix, so for every method) gives ``name``; None if none."""
    from ._params import _param_value

    for text in param_texts:
        key, eq, raw = text.partition("=")
        if eq and key.strip() == name:
            return _param_value(raw)
    return None


def _check_tolerances(tolerances: list[int] | None, n_map: int) -> None:
    """Refuse tolerances of N frames or more on a map of N places, as --k values above N are: no prediction
    is that far off, so recall@t would be 1 whatever the method."""
    above = [t for t in tolerances or [] if t >= n_map]
    if above:
        raise click.UsageError(f"--tolerances {_shown(above)}: recall@t needs t < the map's N = {n_map} places "
                               f"(a prediction is never more than {n_map - 1} places off); give --tolerances "
                               f"values up to {n_map - 1}.")


def _warn_unnamed_pairs(files: dict[str, Path], names: tuple[list[str] | None, list[str] | None],
                        queries: str, db: str | None) -> None:
    """Say on stderr when a --pairs file will hold row indices, not the image names hloc matches by."""
    unnamed = [what for what, found in ((f"--queries {queries}", names[0]),
                                        (f"--db {db}" if db else "the map (no --db)", names[1])) if found is None]
    if not unnamed:
        return
    shown = ", ".join(str(p) for p in list(files.values())[:3]) + (" …" if len(files) > 3 else "")
    _echo_while_running(f"Warning: --pairs: {' and '.join(unnamed)} record no image name per row, so {shown} "
                        "will name those images by row index (from 0), not by the image names hloc matches pairs by. "
                        "Image names come with descriptors written by `btel extract` (listed in FILE.npy.json beside "
                        "FILE.npy) or hloc global-feature .h5 files (FILE.h5[:PREFIX]); give those, or map the indices "
                        "to your images.",
                        err=True)
