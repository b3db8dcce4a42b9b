"""``btel train``: fit a method on map descriptors and save the model file."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import click

from ..methods.roles import DEFAULT_METHOD
from ._inputs import _load_map, calibration_input, check_calibration_options, declared_rows
from ._options import _N_JOBS_HELP, _NO_PROGRESS_HELP, _PARAM_HELP, _check_budget, calibration_options
from ..core.progress import elapsed_ticker
from ._outputs import OTHER_FORMATS, check_output_suffix, refuse_existing
from ._params import ParamCommand, _naming, _param_value, _params_by_method
from .info import _echo_storage

#: Flags of earlier versions, kept working but hidden from --help: each sets one parameter, read as
#: --param reads its VALUE, and goes through the same checks (`--regions 4` is `--param n_regions=4`).
ALIASES = {"regions": "n_regions", "feature-ratio": "feature_ratio", "n-features": "n_features",
           "classifier": "classifier", "dtype": "dtype", "backend": "backend", "scheduler": "scheduler",
           "block-size": "block_size", "code-copies": "code_copies", "exemplar-radius": "exemplar_radius",
           "normalize": "normalize", "whiten": "whiten", "delta": "delta"}


def _alias_name(flag: str) -> str:
    return f"alias_{flag.replace('-', '_')}"


def _aliases(command: Callable[..., Any]) -> Callable[..., Any]:
    """The hidden options of :data:`ALIASES` (and ``--tolerance T``, block_size from a tolerance)."""
    for flag in [*ALIASES, "tolerance"]:
        command = click.option(f"--{flag}", _alias_name(flag), default=None, hidden=True)(command)
    return command


@click.command(cls=ParamCommand)
@click.argument("db", type=click.Path())
@click.option("-o", "--output", "--out", "output", required=True, type=click.Path(dir_okay=False),
              help="Model file to write (.npz).")
@click.option("--overwrite", is_flag=True, help="Replace an existing OUTPUT model file.")
@click.option("--method", default=DEFAULT_METHOD, show_default=True, help="Method name (see `btel methods`).")
@click.option("--budget", default=None,
              help="Byte budget, e.g. 500KB, 2MB, 64KiB (same as --param budget=…).")
@click.option("--param", "param_texts", multiple=True, metavar="NAME=VALUE", help=_PARAM_HELP)
@click.option("--seed", "random_state", type=int, default=None,
              help="Random seed (same as --param random_state=…).")
@click.option("--n-jobs", type=int, default=None, help=_N_JOBS_HELP)
@click.option("--no-progress", is_flag=True, help=_NO_PROGRESS_HELP)
@calibration_options
@click.option("--positive-dist-threshold", type=float, default=None, metavar="METRES",
              help="With --calibrate-truth utm: the positives' radius (default 25).")
@_aliases
def train(db: str, output: str, overwrite: bool, method: str, budget: str | None,
          param_texts: tuple[str, ...], random_state: int | None, n_jobs: int | None, no_progress: bool,
          calibrate: str | None, calibrate_truth: str | None, calibrate_tolerance: int | None,
          positive_dist_threshold: float | None, **aliases: str | None) -> None:
    """Fit a model on map descriptors DB and save it; prints the storage breakdown.

    DB is a .npy matrix (row i = place i; memory-mapped, so maps larger than RAM work), an .npz,
    an hloc .h5, or a folder of .npy shards taken in natural file-name order (shard_2 before shard_10).

    \b
    Any parameter of --method is set with --param NAME=VALUE, e.g.
      btel train db.npy -o m.npz --method pq --param n_subquantizers=16 --param nbits=8
      btel train db.npy -o m.npz --method btel-r --budget 500KB --param n_regions=auto --param whiten=256
    `btel methods --params` lists every method's parameters and their allowed values. The flags of
    earlier versions (--regions, --feature-ratio, --whiten, …) still work as aliases of --param.
    With --method auto, --calibrate QUERIES --calibrate-truth GT chooses among every candidate on
    those labelled queries (never stored in the model); `btel info` shows the table.
    """
    from ..methods.registry import make_method

    shortcuts = _shortcuts(budget, random_state, n_jobs, no_progress, aliases)
    if calibrate_tolerance is not None:
        shortcuts["calibration_tolerance"] = ("--calibrate-tolerance", calibrate_tolerance)
    check_calibration_options(method, calibrate, calibrate_truth, calibrate_tolerance)
    if positive_dist_threshold is not None and calibrate_truth != "utm":
        raise click.UsageError("--positive-dist-threshold is the radius of --calibrate-truth utm (positives from the "
                               "UTM in the image names); a ground-truth file says its own positives.")
    params = _params_by_method([method], param_texts, shortcuts=shortcuts)[method]
    # A model is read by its content, so any name works (map.btel is in use) but one of another format's.
    check_output_suffix(output, "-o", "a model file", (".npz",), refused=OTHER_FORMATS)
    refuse_existing(output, "-o", overwrite, {"DB": db, "--calibrate": calibrate, "--calibrate-truth": calibrate_truth})
    from ..core.limits import check_places

    # A model of more places than answering a query may hold could not be loaded: refused before the map
    # is read (reading checks every value: hours for a sparse 10⁹-row file), and after (other formats).
    check_places(declared_rows(db) or 0, f"a model of DB {db}")
    X = _load_map(db)
    check_places(X.shape[0], f"a model of DB {db}")
    fit_params: dict[str, Any] = {}
    if calibrate:
        Q, truth, said = calibration_input(db, calibrate, calibrate_truth, X.shape[0], positive_dist_threshold)
        fit_params["calibration"] = (Q, truth)
        click.echo(f"calibrating {method} on {Q.shape[0]} labelled queries ({calibrate}); ground truth: "
                   f"{said.get('source')}" + (f", {said['rule']}" if said.get("rule") else ""), err=True)
    from ..evaluation.measure import timed_fit

    with _naming(method):
        model = make_method(method, **params)
        # A method with bars of its own (BTEL's fits, auto's calibration) shows them; any other fit shows
        # the time elapsed (on a terminal; a line every 10 s in a log), so a minute-long fit is not silent.
        own_bars = bool(model.get_params().get("progress")) and (
            bool(calibrate) or not getattr(model, "_bars_only_when_calibrating", False))
        with elapsed_ticker(f"fitting {method} on {X.shape[0]} × {X.shape[1]}",
                            enabled=not no_progress and not own_bars):
            seconds = timed_fit(model, X, **fit_params)
    # Saved before anything is printed: a reader that goes away (`btel train … | head`) ends the command
    # at the next write, and the fit must not be lost with it.
    path = model.save(output, overwrite=overwrite)  # no --overwrite: a racing train's file is never replaced
    regions = f", r = {model.n_regions_} regions" if getattr(model, "n_regions_", 1) > 1 else ""
    click.echo(f"fitted {method}{regions} on {X.shape[0]} places × {X.shape[1]} dims "
               f"in {seconds:.1f} s")
    _echo_storage(model)
    click.echo(f"model written to {path} ({path.stat().st_size:,d} B on disk)")
    if model.get_params().get("budget") is None:  # btel is about budgets: an unbudgeted model is said to be one
        click.echo("no --budget: the model is as large as the method needs; give --budget (e.g. --budget 64KB) "
                   "to fit a byte budget.")


def _shortcuts(budget: str | None, random_state: int | None, n_jobs: int | None, no_progress: bool,
               aliases: dict[str, str | None]) -> dict[str, tuple[str, Any]]:
    """Parameter name → (option, value) of each named option given (see ``_params_by_method``)."""
    if budget is not None:
        _check_budget(budget)
    out: dict[str, tuple[str, Any]] = {
        name: (option, value) for name, option, value in (
            ("budget", "--budget", budget), ("random_state", "--seed", random_state),
            ("n_jobs", "--n-jobs", n_jobs), ("progress", "--no-progress", False if no_progress else None))
        if value is not None}
    given = {flag: aliases[_alias_name(flag)] for flag in [*ALIASES, "tolerance"]
             if aliases[_alias_name(flag)] is not None}
    if "tolerance" in given:
        if "block-size" in given:
            raise click.UsageError("give --block-size or --tolerance, not both.")
        from ..methods.registry import block_size_for_tolerance

        tolerance = _param_value(given.pop("tolerance"))
        if not isinstance(tolerance, int) or isinstance(tolerance, bool) or tolerance < 1:
            raise click.UsageError(f"--tolerance takes a number of frames ≥ 1; got {tolerance!r}.")
        out["block_size"] = ("--tolerance", block_size_for_tolerance(tolerance))
    for flag, text in given.items():
        out[ALIASES[flag]] = (f"--{flag}", _param_value(text))
    return out
