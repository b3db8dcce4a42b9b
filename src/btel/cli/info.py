"""``btel info``: what a saved model is — method, parameters, front end, and the bytes of every array."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import click

from ._params import _param_text


def _echo_storage(model: Any) -> None:
    """What the budget planner chose and the bytes of each stored part (``train`` after fitting, ``info``)."""
    from ..core.storage import budget_of, format_bytes

    breakdown = model.storage_breakdown()
    width = max(len(k) for k in breakdown) if breakdown else 4
    summary = model.summary()  # what a budget planner chose (empty for methods with nothing to add)
    if summary:
        click.echo(summary)
    click.echo("storage breakdown:")
    for name, n in breakdown.items():
        click.echo(f"  {name:<{width}}  {n:>12,d} B")
    click.echo(f"  {'total':<{width}}  {model.nbytes:>12,d} B  ({format_bytes(model.nbytes)})")
    budget = budget_of(model)
    if budget is not None:
        # The method says when its budget did not shape it: the rest is unused, whatever the budget.
        capped = ": the largest model its parameters allow; a larger budget gives the same model" \
            if model.budget_saturated() else ""
        click.echo(f"  {'budget':<{width}}  {budget:>12,d} B  ({model.nbytes / budget:.0%} used{capped})")


def _method_names() -> list[str]:
    from ..methods.registry import METHODS

    return list(METHODS)


def _registry_name(model: Any) -> str:
    """The registry name of this model (``btel-f``) when a preset builds exactly it; else the class
    and the parameters the presets of that class differ in (``BTELocalizer (scheme=compressed, n_regions=4)``)."""
    from functools import partial

    from ..methods.registry import METHODS

    params = model.get_params(deep=False)
    keys: list[str] = []
    for name, factory in METHODS.items():
        cls = factory.func if isinstance(factory, partial) else factory
        if type(model) is not cls:
            continue
        fixed = factory.keywords if isinstance(factory, partial) else {}
        if all(params.get(k) == v for k, v in fixed.items()):
            return name
        keys += [k for k in fixed if k not in keys]
    shown = ", ".join(f"{k}={_param_text(params.get(k))}" for k in keys)
    return f"{type(model).__name__} ({shown})" if shown else type(model).__name__


@click.command()
@click.argument("model_path", metavar="MODEL", type=click.Path(dir_okay=False))
def info(model_path: str) -> None:
    """Show what a saved MODEL is: method, parameters, front end, and the bytes of every stored array."""
    from ..core.fingerprint import describe_fingerprint
    from ..core.params import chosen_at_fit
    from ._inputs import load_model

    model = load_model(model_path, "usage: btel info MODEL")
    name = _registry_name(model)
    click.echo(f"method: {name}" + (f" — {type(model).__name__}" if name in _method_names() else ""))
    click.echo(f"map: N = {model.n_places_} places, d = {model.n_features_in_}; fitted on "
               f"{describe_fingerprint(getattr(model, 'map_fingerprint_', None))}")
    front = model.front_end_
    click.echo(f"front end: normalize={front.normalize}, whiten={front.whiten}, delta={front.delta}"
               f"{'  (uses the query sequence)' if model.uses_query_sequence else ''}")
    params = model.get_params(deep=False)
    runtime = set(getattr(model, "_runtime_params", ()))
    shown = {k: v for k, v in sorted(params.items()) if k not in runtime and k not in ("normalize", "whiten", "delta")}
    picked = chosen_at_fit(model)  # the same values as a run's metrics.json records
    click.echo("parameters: " + ", ".join(
        f"{k}={_param_text(v)}" + (f" (chosen: {_param_text(picked[k])})" if k in picked else "")
        for k, v in shown.items()))
    state = _state_scalars(model)
    if state:
        click.echo("chosen at fit: " + ", ".join(f"{k}={_param_text(v)}" for k, v in state.items()))
    _echo_storage(model)
    _echo_arrays(model)
    click.echo(f"saved by: {_saved_by(model_path)}")
    size = Path(model_path).stat().st_size
    click.echo(f"file size {size:,d} B (container overhead {size - model.nbytes:,d} B)")


def _saved_by(path: str) -> str:
    """``btel 0.1.0 on 2026-11-28T15:04:28+00:00``, from the file's header (checked text only: a header
    is untrusted input), or why it is not known."""
    from ..core.modelfile import load_arrays

    saved = load_arrays(path)[1].get("saved_by")
    version, date = (saved.get("btel"), saved.get("date_utc")) if isinstance(saved, dict) else (None, None)
    if not (isinstance(version, str) and isinstance(date, str)) or len(version) + len(date) > 80:
        return "not recorded (a file written before btel recorded it)"
    return f"btel {version} on {date}"


def _state_scalars(model: Any) -> dict[str, Any]:
    """What fitting decided (the budget planner's choices, sizes): the model's saved state, scalars only."""
    state = model._fitted_state() if callable(getattr(model, "_fitted_state", None)) else {}
    out = {}
    for key, value in state.items():
        if isinstance(value, (bool, int, float, str)) or value is None:
            out[key] = value
        elif isinstance(value, (list, tuple)) and len(value) <= 8 and all(isinstance(v, (int, float)) for v in value):
            out[key] = list(value)
    return out


def _echo_arrays(model: Any) -> None:
    """Every array the model file stores: name, shape, dtype and bytes (front end included)."""
    arrays = {**model.front_end_.arrays(), **model._stored_arrays()}
    if not arrays:
        return
    width = max(len(k) for k in arrays)
    click.echo("stored arrays:")
    for name, a in arrays.items():
        shape = " × ".join(map(str, a.shape)) or "scalar"
        click.echo(f"  {name:<{width}}  {shape:>14}  {str(a.dtype):<8} {a.nbytes:>12,d} B")
