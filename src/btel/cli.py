"""The ``btel`` command line: from descriptors (or images) to a model, predictions and a recall report.

Every subcommand has ``--help``. Failures print one line ``Error: …`` on stderr and exit with a
non-zero code (1 for bad data or models, 2 for bad usage); no traceback unless ``BTEL_DEBUG=1``.

Any parameter of any method is set with ``--param NAME=VALUE`` (``train``, ``evaluate``, ``demo``);
the named BTEL options of ``train`` are shortcuts that fill the same parameters. Names are checked
against the method's ``get_params()`` before anything is fitted.
"""

from __future__ import annotations

import csv
import json
import os
import re
import shlex
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import click
import numpy as np

from . import __version__
from .exceptions import BTELError, InvalidParameterError

_EXPECTED_ERRORS = (BTELError, OSError, ValueError)


class _Group(click.Group):
    """Turns btel's own errors into one-line messages with exit code 1."""

    def invoke(self, ctx: click.Context) -> Any:
        try:
            return super().invoke(ctx)
        except (click.ClickException, click.exceptions.Exit, click.exceptions.Abort):
            raise
        except _EXPECTED_ERRORS as exc:
            if os.environ.get("BTEL_DEBUG"):
                raise
            message = str(exc) or type(exc).__name__
            raise click.ClickException(message.splitlines()[0] if len(message) > 2000 else message) from exc


def _load_matrix(path: str, what: str) -> np.ndarray:
    from .descriptors.npy import load_descriptor_matrix

    return load_descriptor_matrix(path)


def _load_map(path: str) -> np.ndarray:
    """Map descriptors for training: a folder of .npy shards, a memory-mapped .npy, or an .npz."""
    if Path(path).is_dir():
        from .datasets.shards import load_shards

        return load_shards(path)
    from .descriptors.npy import load_descriptor_matrix

    # A .npy map is memory-mapped: pages are read as the fit needs them, never copied whole.
    return load_descriptor_matrix(path, mmap_mode="r" if Path(path).suffix.lower() == ".npy" else None)


def _echo_storage(model: Any) -> None:
    from .storage import format_bytes

    breakdown = model.storage_breakdown()
    width = max(len(k) for k in breakdown) if breakdown else 4
    if hasattr(model, "summary"):  # what a budget planner chose (btel-codes)
        click.echo(model.summary())
    click.echo("storage breakdown:")
    for name, n in breakdown.items():
        click.echo(f"  {name:<{width}}  {n:>12,d} B")
    click.echo(f"  {'total':<{width}}  {model.nbytes:>12,d} B  ({format_bytes(model.nbytes)})")


_VALUE_HELP = ("VALUE is read as JSON when it is a JSON literal (3, 0.5, true, null, \"x\"), else kept as text "
               "(auto, float16). `btel methods --params` lists every method's parameters.")
_PARAM_HELP = "A parameter of --method, NAME=VALUE (repeatable), e.g. --param sparsity=0.05. " + _VALUE_HELP
_PARAMS_HELP = ("A parameter NAME=VALUE of every method in --methods, or METHOD:NAME=VALUE of one of them "
                "(repeatable), e.g. --param btel-r:n_regions=10. " + _VALUE_HELP)


def _param_value(text: str) -> Any:
    """VALUE of ``--param NAME=VALUE``: the JSON literal it spells (``3``, ``0.5``, ``true``, ``null``,
    ``"x"``, ``[1, 2]``), else the text itself (``auto``, ``float16``). NaN and Infinity stay text."""
    def reject(constant: str) -> Any:
        raise ValueError(constant)

    try:
        return json.loads(text, parse_constant=reject)
    except ValueError:
        return text


def _valid_params(method: str) -> list[str]:
    """Parameter names of ``method`` (its ``get_params()`` keys), sorted."""
    from .methods import make_method

    return sorted(make_method(method).get_params())


def _params_by_method(methods: list[str], param_texts: tuple[str, ...], *,
                      shortcuts: dict[str, tuple[str, Any]] | None = None,
                      base: dict[str, dict[str, Any]] | None = None) -> dict[str, dict[str, Any]]:
    """Each method's parameters, every name checked against its ``get_params()`` before anything is fitted.

    Layers, later ones overriding: ``base`` (per method, the command's own defaults), ``shortcuts``
    (parameter name → (option, value) of each named option given), ``--param NAME=VALUE`` (every
    method), ``--param METHOD:NAME=VALUE`` (that method). A shortcut and ``--param`` setting the same
    name, or one name given twice in one layer, is a usage error; so is a name a method does not have.
    """
    shortcuts = shortcuts or {}
    general: dict[str, Any] = {}
    targeted: dict[str, dict[str, Any]] = {}
    for text in param_texts:
        key, eq, raw = text.partition("=")
        target, _, name = key.strip().rpartition(":")
        if not eq or not name.isidentifier():
            raise click.UsageError(f"--param {text!r} is not NAME=VALUE (or METHOD:NAME=VALUE), e.g. feature_ratio=0.25.")
        if target and target not in methods:
            raise click.UsageError(f"--param {text!r} is for {target!r}, which is not a method of this run "
                                   f"({', '.join(methods)}).")
        layer = targeted.setdefault(target, {}) if target else general
        if name in layer:
            raise click.UsageError(f"--param sets {key.strip()} twice; give it once.")
        if name in shortcuts:
            raise click.UsageError(f"{shortcuts[name][0]} and --param {key.strip()}=… both set {name}; give one of them.")
        layer[name] = _param_value(raw)
    out: dict[str, dict[str, Any]] = {}
    for method in methods:
        valid = _valid_params(method)
        for name, (option, _) in shortcuts.items():
            if name not in valid:
                raise click.UsageError(f"{option} sets parameter {name!r}, which {method} does not have; "
                                       f"{method} takes: {', '.join(valid)}.")
        given = {**general, **targeted.get(method, {})}
        for name in given:
            if name not in valid:
                hint = (f" (--param {name}=… applies to every method; write METHOD:{name}=… for one)"
                        if name in general and len(methods) > 1 else "")
                raise click.UsageError(f"{method} has no parameter {name!r}{hint}; {method} takes: {', '.join(valid)}.")
        out[method] = {**(base or {}).get(method, {}), **{n: v for n, (_, v) in shortcuts.items()}, **given}
    return out


@contextmanager
def _naming(method: str) -> Iterator[None]:
    """A bad parameter value found while building, fitting or evaluating ``method`` names the method."""
    try:
        yield
    except InvalidParameterError as exc:
        # The estimator names its class ("BTELocalizer: C must be …"); the user chose a method name.
        message = re.sub(r"^[A-Z][A-Za-z]+: ", "", str(exc))
        raise InvalidParameterError(f"{method}: {message}") from exc


@click.group(cls=_Group, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, prog_name="btel")
def main() -> None:
    """btel: visual place recognition under a storage budget (binary tree encoding, BTEL).

    \b
    Typical path:
      btel extract IMAGES_DIR -o db.npy --descriptor hog
      btel train db.npy -o map.btel.npz --budget 500KB
      btel localize map.btel.npz queries.npy -o predictions.csv
      btel evaluate --db db.npy --queries queries.npy --methods btel-c,btel-r,pq --budget 500KB --out runs/x
    Try `btel demo` first: it needs no data.
    """


@main.command()
@click.option("--places", "n_places", default=2000, show_default=True, help="Places on the synthetic route.")
@click.option("--dim", default=512, show_default=True, help="Descriptor dimension.")
@click.option("--budget", default="64KB", show_default=True, help="Byte budget for every method (KB = 1000 B).")
@click.option("--methods", default="btel-c,btel-r,pq,bruteforce", show_default=True,
              help="Comma-separated method names (see `btel methods`); bruteforce ignores the budget.")
@click.option("--seed", default=0, show_default=True, help="Random seed of the route.")
@click.option("--param", "param_texts", multiple=True, metavar="[METHOD:]NAME=VALUE", help=_PARAMS_HELP)
@click.option("--out", "out_dir", type=click.Path(file_okay=False), default=None,
              help="Run folder for metrics.json, CSV and plots (default: runs/demo-<time>).")
def demo(n_places: int, dim: int, budget: str, methods: str, seed: int, param_texts: tuple[str, ...],
         out_dir: str | None) -> None:
    """Run the main job on the embedded default: a synthetic route, several methods, a table and a plot.

    The route is generated by btel itself (btel.datasets.synthetic_route): a map traverse and a
    query traverse under an appearance change. Every method but brute force gets the same budget.
    """
    from .datasets import synthetic_route
    from .evaluation import evaluate
    from .methods import make_method
    from .runs import write_run

    names = _split(methods)
    params = _params_by_method(names, param_texts, base={
        name: {} if name in ("bruteforce", "seqslam") else {"budget": budget} for name in names})
    route = synthetic_route(n_places, dim, seed=seed)
    click.echo(f"synthetic route: N = {n_places} places, d = {dim}, map + 1 query traverse (seed {seed})")
    results = []
    for name in names:
        with _naming(name):
            results.append(evaluate(make_method(name, **params[name]), route.map, route.queries, name=name))
    _print_table(results)
    out = Path(out_dir) if out_dir else Path("runs") / time.strftime("demo-%Y%m%d-%H%M%S")
    report = write_run(results, out, command=_command_line(), extra={"data": "synthetic_route", "seed": seed})
    click.echo(f"run folder: {report.out_dir}")


@main.command()
@click.argument("images_dir", type=click.Path(file_okay=False))
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False), help="Descriptor matrix to write (.npy).")
@click.option("--descriptor", default="hog", show_default=True,
              help="hog | patchnorm | densevlad, or a descriptor file saved with --save-descriptor.")
@click.option("--fit-on", type=click.Path(file_okay=False), default=None,
              help="Map image folder to learn from (DenseVLAD vocabulary + PCA). Never the queries.")
@click.option("--save-descriptor", type=click.Path(dir_okay=False), default=None,
              help="Write the fitted descriptor (e.g. the DenseVLAD vocabulary) to describe the queries with it.")
@click.option("--force", is_flag=True, help="Recompute even if OUTPUT is up to date.")
@click.option("--no-progress", is_flag=True, help="No progress bar.")
def extract(images_dir: str, output: str, descriptor: str, fit_on: str | None, save_descriptor: str | None,
            force: bool, no_progress: bool) -> None:
    """Describe every image in IMAGES_DIR (natural file-name order = route order) into one .npy matrix.

    Row i of OUTPUT is the i-th image. A JSON file beside OUTPUT records the descriptor and the
    images; when nothing changed, the existing OUTPUT is reused (a cache) unless --force.
    """
    from .descriptors import get_descriptor
    from .descriptors.base import load_descriptor
    from .descriptors.extract import extract_cached

    model = load_descriptor(descriptor) if Path(descriptor).is_file() else get_descriptor(descriptor)
    X, reused = extract_cached(images_dir, output, model, fit_on=fit_on, progress=not no_progress, force=force)
    if reused:
        click.echo(f"{output} is up to date ({X.shape[0]} images, {descriptor}); use --force to recompute")
        return
    click.echo(f"{X.shape[0]} images → {X.shape[1]}-D {type(model).__name__} descriptors written to {output}")
    if save_descriptor:
        model.save(save_descriptor)
        click.echo(f"fitted descriptor written to {save_descriptor}")


@main.command()
@click.argument("db", type=click.Path())
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False), help="Model file to write (.npz).")
@click.option("--method", default="btel-c", show_default=True, help="Method name (see `btel methods`).")
@click.option("--budget", default=None, help="Byte budget, e.g. 500KB, 2MB, 64KiB.")
@click.option("--param", "param_texts", multiple=True, metavar="NAME=VALUE", help=_PARAM_HELP)
@click.option("--regions", default=None, help="BTEL: number of regions r, or 'auto'.")
@click.option("--feature-ratio", type=float, default=None, help="BTEL: c = d'/d.")
@click.option("--n-features", type=int, default=None, help="BTEL: d' directly.")
@click.option("--classifier", type=click.Choice(["svm", "logistic"]), default=None, help="BTEL classifier.")
@click.option("--dtype", type=click.Choice(["float32", "float16"]), default=None, help="BTEL stored weight dtype.")
@click.option("--n-jobs", type=int, default=None, help="Parallel fits (-1 = all cores).")
@click.option("--backend", type=click.Choice(["threads", "loky", "dask"]), default=None,
              help="BTEL: where the classifier fits run — threads (default), loky processes, or a Dask cluster "
                   "(pip install btel[dask]).")
@click.option("--scheduler", default=None, help="With --backend dask: the scheduler address, e.g. tcp://10.0.0.5:8786.")
@click.option("--no-progress", is_flag=True, help="BTEL: no progress bar.")
@click.option("--seed", "random_state", type=int, default=None, help="Random seed (random_state).")
@click.option("--block-size", type=int, default=None,
              help="BTEL: tolerance-aware codes, index blocks of B places and answer the block centre.")
@click.option("--tolerance", type=int, default=None,
              help="BTEL: the tolerance t you need (frames); sets --block-size to the largest power of two ≤ t.")
@click.option("--code-copies", type=int, default=None, help="BTEL: offset (error-correcting) codes, m copies.")
@click.option("--exemplar-radius", type=int, default=None, help="BTEL: multi-exemplar weights within ±e places.")
def train(db: str, output: str, method: str, budget: str | None, param_texts: tuple[str, ...], regions: str | None,
          feature_ratio: float | None, n_features: int | None, classifier: str | None, dtype: str | None,
          n_jobs: int | None, backend: str | None, scheduler: str | None, no_progress: bool,
          random_state: int | None, block_size: int | None, tolerance: int | None, code_copies: int | None,
          exemplar_radius: int | None) -> None:
    """Fit a model on map descriptors DB and save it; prints the storage breakdown.

    DB is a .npy matrix (row i = place i; memory-mapped, so maps larger than RAM work), an .npz,
    or a folder of .npy shards taken in natural file-name order (shard_2 before shard_10).

    \b
    Any parameter of --method is set with --param NAME=VALUE, e.g.
      btel train db.npy -o m.npz --method pq --param n_subquantizers=16 --param nbits=8

    --budget and the options after --param are shortcuts that fill the same parameters (--regions
    is n_regions, --seed random_state, --no-progress progress=false, --block-size and --tolerance
    block_size, the others by their own names). Each must be a parameter of --method (see `btel
    methods --params`), and a shortcut and --param may not set the same one.
    """
    from .methods import make_method

    if scheduler is not None and backend != "dask":
        raise click.UsageError("--scheduler only applies with --backend dask.")
    if block_size is not None and tolerance is not None:
        raise click.UsageError("give --block-size or --tolerance, not both.")
    if tolerance is not None:
        from .localizer import block_size_for_tolerance

        block_size = block_size_for_tolerance(tolerance)
    n_regions: Any = None
    if regions is not None:
        n_regions = regions if regions == "auto" else _int(regions, "--regions")
    named = {"budget": ("--budget", budget), "n_regions": ("--regions", n_regions),
             "feature_ratio": ("--feature-ratio", feature_ratio), "n_features": ("--n-features", n_features),
             "classifier": ("--classifier", classifier), "dtype": ("--dtype", dtype), "n_jobs": ("--n-jobs", n_jobs),
             "backend": ("--backend", backend), "scheduler": ("--scheduler", scheduler),
             "progress": ("--no-progress", False if no_progress else None),
             "random_state": ("--seed", random_state),
             "block_size": ("--tolerance" if tolerance is not None else "--block-size", block_size),
             "code_copies": ("--code-copies", code_copies), "exemplar_radius": ("--exemplar-radius", exemplar_radius)}
    shortcuts = {name: (option, value) for name, (option, value) in named.items() if value is not None}
    params = _params_by_method([method], param_texts, shortcuts=shortcuts)[method]
    X = _load_map(db)
    start = time.perf_counter()
    with _naming(method):
        model = make_method(method, **params)
        model.fit(X)
    regions = f", r = {model.n_regions_} regions" if getattr(model, "n_regions_", 1) > 1 else ""
    click.echo(f"fitted {method}{regions} on {X.shape[0]} places × {X.shape[1]} dims "
               f"in {time.perf_counter() - start:.1f} s")
    _echo_storage(model)
    path = model.save(output)
    click.echo(f"model written to {path} ({path.stat().st_size:,d} B on disk)")


@main.command()
@click.argument("model_path", metavar="MODEL", type=click.Path(dir_okay=False))
@click.argument("queries", required=False, type=click.Path(dir_okay=False))
@click.option("-o", "--output", type=click.Path(dir_okay=False), help="Predictions CSV to write (not with --stream).")
@click.option("--sequence-filter", "window", type=int, default=None,
              help="Apply the paper's sequence filter with window a (queries must be consecutive frames).")
@click.option("--stream", is_flag=True,
              help="Read one descriptor per line (numbers separated by commas/spaces) from stdin or --input and "
                   "print one prediction per line as each arrives.")
@click.option("--input", "input_path", type=click.Path(dir_okay=False), default=None,
              help="With --stream: read this text file instead of stdin.")
@click.option("--hmm", is_flag=True,
              help="Decode the queries as one ordered traverse with the HMM over places (forward motion; no extra "
                   "stored bytes) instead of frame by frame; online (one update per frame) with --stream.")
@click.option("--top-k", type=int, default=None,
              help="Batch: also write the K most likely places per query (ranked output) as columns rank_1…rank_K.")
@click.option("--follow", is_flag=True, help="With --stream --input: keep reading as the file grows (like tail -f).")
@click.option("--idle-timeout", type=float, default=None,
              help="With --follow: stop after this many seconds without a new line (default: run until Ctrl-C).")
def localize(model_path: str, queries: str | None, output: str | None, window: int | None, stream: bool,
             input_path: str | None, hmm: bool, top_k: int | None, follow: bool, idle_timeout: float | None) -> None:
    """Predict the place of every query with a saved MODEL.

    \b
    Batch:  btel localize MODEL QUERIES.npy -o predictions.csv   (writes query,prediction CSV)
    Stream: producer | btel localize MODEL --stream --sequence-filter 5   (or --hmm)
            btel localize MODEL --stream --input frames.txt --follow
    In stream mode each line of input is one descriptor; each output line is the place index of the
    next well-formed input line. A malformed line (wrong count, not a number, NaN) gets a one-line
    error naming its line number on stderr, produces no output line, and the stream goes on.
    """
    from . import load
    from .sequence import filter_sequence

    if stream:
        if top_k is not None:
            raise click.UsageError("--top-k applies to batch localization, not --stream.")
        if hmm and window is not None:
            raise click.UsageError("choose --hmm or --sequence-filter, not both.")
        if queries is not None or output is not None:
            raise click.UsageError("--stream reads stdin (or --input) and writes stdout; drop QUERIES and -o.")
        _localize_stream(load(model_path), input_path, follow, idle_timeout, window, hmm)
        return
    if input_path is not None or follow or idle_timeout is not None:
        raise click.UsageError("--input, --follow and --idle-timeout only apply with --stream.")
    if queries is None or output is None:
        raise click.UsageError("give QUERIES and -o/--output (or use --stream).")
    if hmm and window is not None:
        raise click.UsageError("choose --hmm or --sequence-filter, not both.")
    model = load(model_path)
    Q = _load_matrix(queries, "query descriptors")
    if top_k is not None and not getattr(model, "supports_ranking", True):
        raise click.UsageError(f"{type(model).__name__} does not rank candidates; drop --top-k.")
    predictions = model.predict_sequence(Q, "hmm") if hmm else model.predict(Q)
    if window is not None:
        predictions = filter_sequence(predictions, window, n_places=model.n_places_)
    ranked = model.rank(Q, top_k) if top_k is not None else None
    Path(output).parent.mkdir(parents=True, exist_ok=True)
    with open(output, "w", newline="") as fh:
        writer = csv.writer(fh)
        head = ["query", "prediction"]
        if ranked is not None:
            head += [f"rank_{j + 1}" for j in range(ranked.shape[1])]
        writer.writerow(head)
        for i, p in enumerate(predictions.tolist()):
            writer.writerow([i, p, *(ranked[i].tolist() if ranked is not None else [])])
    click.echo(f"{len(predictions)} predictions written to {output}")


def _localize_stream(model: Any, input_path: str | None, follow: bool, idle_timeout: float | None,
                     window: int | None, hmm: bool = False) -> None:
    """The --stream loop: one flushed output line per well-formed input line."""
    from .streaming import localize_stream

    if follow and input_path is None:
        raise click.UsageError("--follow needs --input FILE (stdin already waits for new lines).")
    if idle_timeout is not None and not follow:
        raise click.UsageError("--idle-timeout only applies with --follow.")
    n_bad = n_out = 0

    def report(line_number: int, message: str) -> None:
        nonlocal n_bad
        n_bad += 1
        click.echo(f"error: line {line_number}: {message} (skipped)", err=True)

    source = open(input_path) if input_path is not None else sys.stdin
    try:
        for _, place in localize_stream(model, source, window=window, on_error=report, follow=follow,
                                        idle_timeout=idle_timeout, hmm=hmm):
            click.echo(place)  # click.echo flushes: a reader of the pipe sees each line at once
            n_out += 1
    except KeyboardInterrupt:  # stopping a --follow stream is the normal way to end it
        pass
    finally:
        if input_path is not None:
            source.close()
    if n_bad:
        click.echo(f"{n_out} predictions; {n_bad} malformed line(s) skipped", err=True)


@main.command(name="evaluate")
@click.option("--db", type=click.Path(dir_okay=False), default=None, help="Map descriptors (.npy) to fit --methods on.")
@click.option("--model", "model_paths", multiple=True, type=click.Path(dir_okay=False),
              help="A saved model to evaluate instead of fitting (repeatable).")
@click.option("--queries", required=True, type=click.Path(dir_okay=False), help="Query descriptors (.npy), one query per row.")
@click.option("--methods", default="btel-c", show_default=True, help="Comma-separated method names (with --db).")
@click.option("--budget", default=None, help="Byte budget for every method.")
@click.option("--param", "param_texts", multiple=True, metavar="[METHOD:]NAME=VALUE", help=_PARAMS_HELP)
@click.option("--ground-truth", type=click.Path(dir_okay=False), default=None,
              help="Ground-truth file (.npz/.npy/.mat); default: frame-aligned (query j is place j).")
@click.option("--out", "out_dir", required=True, type=click.Path(file_okay=False), help="Run folder.")
@click.option("--overwrite", is_flag=True, help="Replace the run files in an existing run folder.")
def evaluate_cmd(db: str | None, model_paths: tuple[str, ...], queries: str, methods: str, budget: str | None,
                 param_texts: tuple[str, ...], ground_truth: str | None, out_dir: str, overwrite: bool) -> None:
    """Localize QUERIES with each method and write metrics.json, metrics.csv, predictions and plots to --out.

    Methods are fitted on --db (by name, --methods, each with --budget and its --param values), or
    loaded from saved --model files (which keep the parameters they were fitted with).
    """
    from . import load
    from .datasets import GroundTruth
    from .evaluation import evaluate
    from .methods import make_method
    from .runs import write_run

    if db is None and not model_paths:
        raise click.UsageError("give --db (to fit --methods) or at least one --model.")
    if param_texts and db is None:
        raise click.UsageError("--param sets parameters of the methods fitted on --db; saved --model files keep theirs.")
    names = _split(methods) if db is not None else []
    params = _params_by_method(names, param_texts, base={name: {"budget": budget} if budget else {} for name in names})
    Q = _load_matrix(queries, "query descriptors")
    gt = GroundTruth.from_file(ground_truth) if ground_truth else None
    results = []
    for path in model_paths:
        click.echo(f"evaluating saved model {path} …")
        results.append(evaluate(load(path), None, Q, name=Path(path).name.split(".")[0], ground_truth=gt, fit=False))
    if db is not None:
        X = _load_matrix(db, "map descriptors")
        if X.shape[1] != Q.shape[1]:
            raise click.ClickException(
                f"--db has {X.shape[1]} dims but --queries has {Q.shape[1]}; describe both with the same descriptor.")
        for name in names:
            click.echo(f"evaluating {name} …")
            with _naming(name):
                results.append(evaluate(make_method(name, **params[name]), X, Q, name=name, ground_truth=gt))
    _print_table(results)
    report = write_run(results, out_dir, command=_command_line(), overwrite=overwrite,
                       extra={"db": str(Path(db).resolve()) if db else None, "models": list(model_paths),
                              "queries": str(Path(queries).resolve()), "budget": budget})
    click.echo(f"run folder: {report.out_dir}")


@main.command(name="methods")
@click.option("--params", "show_params", is_flag=True, help="Also list each method's parameters and defaults.")
def methods_cmd(show_params: bool) -> None:
    """List the registered method names (and, with --params, what --param can set)."""
    from .methods import METHODS, make_method

    for name in METHODS:
        if not show_params:
            click.echo(name)
            continue
        defaults = sorted(make_method(name).get_params().items())
        click.echo(f"{name}: " + ", ".join(f"{k}={_param_text(v)}" for k, v in defaults))


@main.command()
@click.argument("model_path", metavar="MODEL", type=click.Path(dir_okay=False))
def info(model_path: str) -> None:
    """Show what a saved MODEL is and what it stores."""
    from . import load

    model = load(model_path)
    click.echo(f"{type(model).__name__}: N = {model.n_places_} places, d = {model.n_features_in_}")
    _echo_storage(model)
    size = Path(model_path).stat().st_size
    click.echo(f"file size {size:,d} B (container overhead {size - model.nbytes:,d} B)")


@main.command()
@click.argument("name", metavar="NAME")
@click.option("--data", "data_root", type=click.Path(file_okay=False), default=None,
              help="Folder with summer/ and winter/ (default ../shared/data/nordland64).")
@click.option("--out", "out_dir", type=click.Path(file_okay=False), default="runs/experiments", show_default=True,
              help="Runs folder; results go to OUT/NAME/.")
@click.option("--cache", "cache_dir", type=click.Path(file_okay=False), default=None,
              help="Descriptor cache (default OUT/cache).")
@click.option("--quick", is_flag=True, help="Small version (first 300 frames, few points): for tests and smoke runs.")
def experiment(name: str, data_root: str | None, out_dir: str, cache_dir: str | None, quick: bool) -> None:
    """Run one of the paper's experiments on Nordland (or 'all').

    \b
    NAME: accuracy | vs-n | vs-budget | feature-ratio | regions | sequence-filter | beyond | codes | all
    Each writes results.csv, results.json and PNG plots into OUT/NAME/; `btel report` turns the
    latest runs into docs/results.md.
    """
    from .experiments import EXPERIMENTS, describe_row, run_experiment

    names = list(EXPERIMENTS) if name == "all" else [name]
    for n in names:
        click.echo(f"experiment {n}{' (quick)' if quick else ''} …")
        run = run_experiment(n, data_root=data_root, out_dir=out_dir, cache_dir=cache_dir, quick=quick,
                             command=_command_line())
        for row in run.rows:
            click.echo("  " + describe_row(row))
        click.echo(f"  written to {run.out_dir}")


@main.command()
@click.option("--runs", "runs_dir", type=click.Path(file_okay=False), default="runs/experiments", show_default=True)
@click.option("--docs", "docs_dir", type=click.Path(file_okay=False), default="docs", show_default=True)
def report(runs_dir: str, docs_dir: str) -> None:
    """Write docs/results.md and docs/results.json (plus figures) from the latest experiment runs."""
    from .report import write_report

    path = write_report(runs_dir, docs_dir)
    click.echo(f"written {path} and {path.with_suffix('.json')}")


def _split(methods: str) -> list[str]:
    names = [m.strip() for m in methods.split(",") if m.strip()]
    if not names:
        raise click.UsageError("--methods is empty; give at least one method name (see `btel methods`).")
    return names


def _param_text(value: Any) -> str:
    """How to write ``value`` after --param NAME= (text as is unless it would read as JSON)."""
    if isinstance(value, str) and _param_value(value) == value:
        return value
    try:
        return json.dumps(value)
    except TypeError:
        return repr(value)


def _int(value: str, flag: str) -> int:
    try:
        return int(value)
    except ValueError:
        raise click.UsageError(f"{flag} must be an integer or 'auto'; got {value!r}.") from None


def _command_line() -> str:
    return shlex.join(["btel", *sys.argv[1:]])


def _print_table(results: list[Any]) -> None:
    from .storage import format_bytes

    tolerances = list(results[0].recall) if results else []
    header = f"{'method':<12} {'bytes':>10} {'fit s':>7} {'µs/query':>9} " + " ".join(f"{'R@t=' + str(t):>7}" for t in tolerances)
    click.echo(header)
    click.echo("-" * len(header))
    for r in results:
        size = format_bytes(r.nbytes) if r.nbytes is not None else "?"
        fit = f"{r.fit_time_s:.1f}" if r.fit_time_s is not None else "-"
        recalls = " ".join(f"{r.recall[t]:>7.3f}" for t in tolerances)
        click.echo(f"{r.name:<12} {size:>10} {fit:>7} {r.query_time_s_per_query * 1e6:>9.1f} {recalls}")


if __name__ == "__main__":  # pragma: no cover
    main()
