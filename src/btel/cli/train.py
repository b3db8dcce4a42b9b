"""``btel train``: fit a method on map descriptors and save the model file."""

from __future__ import annotations

import time
from typing import Any

import click

from ..methods.roles import DEFAULT_METHOD
from ._inputs import _load_map
from ._jobs import _naming, _params_by_method
from ._options import _DELTA_HELP, _FRONT_END_HELP, _N_JOBS_HELP, _NO_PROGRESS_HELP, _PARAM_HELP, _check_budget
from ._outputs import refuse_existing
from .info import _echo_storage


@click.command()
@click.argument("db", type=click.Path())
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False), help="Model file to write (.npz).")
@click.option("--overwrite", is_flag=True, help="Replace an existing OUTPUT model file.")
@click.option("--method", default=DEFAULT_METHOD, show_default=True, help="Method name (see `btel methods`).")
@click.option("--budget", default=None, help="Byte budget, e.g. 500KB, 2MB, 64KiB.")
@click.option("--param", "param_texts", multiple=True, metavar="NAME=VALUE", help=_PARAM_HELP)
@click.option("--regions", default=None, help="BTEL: number of regions r, or 'auto'.")
@click.option("--feature-ratio", type=float, default=None, help="BTEL: c = d'/d.")
@click.option("--n-features", type=int, default=None, help="BTEL: d' directly.")
@click.option("--classifier", type=click.Choice(["svm", "logistic"]), default=None, help="BTEL classifier.")
@click.option("--dtype", type=click.Choice(["float32", "float16"]), default=None, help="BTEL stored weight dtype.")
@click.option("--n-jobs", type=int, default=None, help=_N_JOBS_HELP)
@click.option("--backend", type=click.Choice(["threads", "loky", "dask"]), default=None,
              help="BTEL: where the classifier fits run — threads (default), loky processes, or a Dask cluster "
                   "(pip install btel[dask]).")
@click.option("--scheduler", default=None, help="With --backend dask: the scheduler address, e.g. tcp://10.0.0.5:8786.")
@click.option("--no-progress", is_flag=True, help=_NO_PROGRESS_HELP)
@click.option("--seed", "random_state", type=int, default=None, help="Random seed (random_state).")
@click.option("--block-size", type=int, default=None,
              help="BTEL: tolerance-aware codes, index blocks of B places and answer the block centre.")
@click.option("--tolerance", type=int, default=None,
              help="BTEL: the tolerance t you need (frames); sets --block-size to the largest power of two ≤ t.")
@click.option("--code-copies", type=int, default=None, help="BTEL: offset (error-correcting) codes, m copies.")
@click.option("--exemplar-radius", type=int, default=None, help="BTEL: multi-exemplar weights within ±e places.")
@click.option("--normalize", type=click.Choice(["none", "l2", "power"]), default=None, help=_FRONT_END_HELP)
@click.option("--whiten", type=int, default=None, metavar="P", help="PCA-whiten to P dimensions (front end).")
@click.option("--delta", type=int, default=None, metavar="W", help=_DELTA_HELP)
@click.option("--calibrate", "calibrate", type=click.Path(), default=None, metavar="QUERIES",
              help="auto: labelled query descriptors to choose the method on (scored, never stored in the "
                   "model).")
@click.option("--calibrate-truth", type=click.Path(dir_okay=False), default=None, metavar="GT",
              help="With --calibrate: their ground truth, any file --ground-truth of `btel evaluate` reads, "
                   "or 'utm' (positions in the image names of DB and QUERIES). Default: frame-aligned.")
@click.option("--calibrate-tolerance", type=click.IntRange(min=0), default=None, metavar="T",
              help="With --calibrate and true places: correct within T places (calibration_tolerance; "
                   "default 0).")
def train(db: str, output: str, overwrite: bool, method: str, budget: str | None, param_texts: tuple[str, ...], regions: str | None,
          feature_ratio: float | None, n_features: int | None, classifier: str | None, dtype: str | None,
          n_jobs: int | None, backend: str | None, scheduler: str | None, no_progress: bool,
          random_state: int | None, block_size: int | None, tolerance: int | None, code_copies: int | None,
          exemplar_radius: int | None, normalize: str | None, whiten: int | None, delta: int | None,
          calibrate: str | None = None, calibrate_truth: str | None = None,
          calibrate_tolerance: int | None = None) -> None:
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

    \b
    With --method auto and labelled queries, --calibrate QUERIES --calibrate-truth GT chooses among
    every candidate on those queries (btel.methods.auto.calibrate); `btel info` shows the table.
    """
    from ..methods.registry import make_method

    if scheduler is not None and backend != "dask":
        raise click.UsageError("--scheduler only applies with --backend dask.")
    if block_size is not None and tolerance is not None:
        raise click.UsageError("give --block-size or --tolerance, not both.")
    if tolerance is not None:
        from ..methods.registry import block_size_for_tolerance

        block_size = block_size_for_tolerance(tolerance)
    n_regions: Any = None
    if regions is not None:
        n_regions = _regions(regions)
    named = {"budget": ("--budget", budget), "n_regions": ("--regions", n_regions),
             "feature_ratio": ("--feature-ratio", feature_ratio), "n_features": ("--n-features", n_features),
             "classifier": ("--classifier", classifier), "dtype": ("--dtype", dtype), "n_jobs": ("--n-jobs", n_jobs),
             "backend": ("--backend", backend), "scheduler": ("--scheduler", scheduler),
             "progress": ("--no-progress", False if no_progress else None),
             "random_state": ("--seed", random_state),
             "block_size": ("--tolerance" if tolerance is not None else "--block-size", block_size),
             "code_copies": ("--code-copies", code_copies), "exemplar_radius": ("--exemplar-radius", exemplar_radius),
             "normalize": ("--normalize", normalize), "whiten": ("--whiten", whiten), "delta": ("--delta", delta)}
    if calibrate is None and (calibrate_truth is not None or calibrate_tolerance is not None):
        raise click.UsageError("--calibrate-truth and --calibrate-tolerance apply with --calibrate QUERIES.")
    if calibrate is not None and "calibration" not in _fit_parameters(method):
        raise click.UsageError(f"--calibrate chooses a method on labelled queries, which --method {method} "
                               "does not do. Use --method auto (or compare methods with `btel evaluate`).")
    named["calibration_tolerance"] = ("--calibrate-tolerance", calibrate_tolerance)
    shortcuts = {name: (option, value) for name, (option, value) in named.items() if value is not None}
    if budget is not None:
        _check_budget(budget)
    params = _params_by_method([method], param_texts, shortcuts=shortcuts)[method]
    refuse_existing(output, "-o", overwrite)
    X = _load_map(db)
    calibration = None if calibrate is None else _calibration(db, calibrate, calibrate_truth, X.shape[0])
    start = time.perf_counter()
    with _naming(method):
        model = make_method(method, **params)
        model.fit(X) if calibration is None else model.fit(X, calibration=calibration)
    regions = f", r = {model.n_regions_} regions" if getattr(model, "n_regions_", 1) > 1 else ""
    click.echo(f"fitted {method}{regions} on {X.shape[0]} places × {X.shape[1]} dims "
               f"in {time.perf_counter() - start:.1f} s")
    _echo_storage(model)
    path = model.save(output, overwrite=overwrite)  # no --overwrite: a racing train's file is never replaced
    click.echo(f"model written to {path} ({path.stat().st_size:,d} B on disk)")


def _fit_parameters(method: str) -> set[str]:
    """The parameters of ``method``'s fit (``calibration`` where it chooses on labelled queries)."""
    import inspect

    from ..methods.registry import make_method

    return set(inspect.signature(make_method(method).fit).parameters)


def _calibration(db: str, queries: str, truth: str | None, n_map: int) -> tuple[Any, Any]:
    """``--calibrate QUERIES --calibrate-truth GT``: the labelled queries and their ground truth."""
    from ..datasets import GroundTruth
    from ..exceptions import InvalidParameterError
    from ._inputs import _load_matrix

    Q = _load_matrix(queries, "calibration queries")
    if truth == "utm":
        from ..datasets.vpr_names import DEFAULT_POSITIVE_DIST_THRESHOLD
        from ._names import utm_ground_truth

        return Q, utm_ground_truth(db, queries, n_map, Q.shape[0], DEFAULT_POSITIVE_DIST_THRESHOLD)
    try:
        gt = (GroundTruth.frame_aligned(Q.shape[0], n_map=n_map) if truth is None
              else GroundTruth.from_file(truth, n_queries=Q.shape[0], n_map=n_map))
    except InvalidParameterError as exc:
        raise click.ClickException(f"--calibrate-truth: {exc}") from None
    return Q, gt.query_places if gt.kind == "places" else gt


def _regions(text: str) -> int | str:
    """``--regions``: an integer, or a word that ``n_regions`` accepts (asked of the registered methods that
    have the parameter, so the command line does not spell their options)."""
    try:
        return int(text)
    except ValueError:
        pass
    from ..exceptions import InvalidParameterError
    from ..methods.registry import METHODS, make_method

    for name in METHODS:
        if "n_regions" in make_method(name).get_params():
            try:
                make_method(name, n_regions=text)
            except InvalidParameterError:
                continue
            return text
    raise click.UsageError(f"--regions must be an integer or 'auto'; got {text!r}.")
