"""``--param NAME=VALUE``, the one way to set a method's parameters: names checked against the
method's ``get_params()``, values against its declared ``_parameter_constraints``, before anything is
fitted; a refusal is a usage error in the command line's words."""

from __future__ import annotations

import json
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

import click


def _param_value(text: str) -> Any:
    """VALUE of ``--param NAME=VALUE``: the JSON literal it spells (``3``, ``0.5``, ``true``, ``null``,
    ``"x"``, ``[1, 2]``), else the text itself (``auto``, ``float16``). NaN and Infinity stay text."""
    def reject(constant: str) -> Any:
        raise ValueError(constant)

    try:
        return json.loads(text, parse_constant=reject)
    except ValueError:
        return text


def _param_text(value: Any) -> str:
    """How to write ``value`` after --param NAME= (text as is unless it would read as JSON)."""
    if isinstance(value, str) and _param_value(value) == value:
        return value
    try:
        return json.dumps(value)
    except TypeError:
        return repr(value)


def _method_class(method: str) -> type:
    """The class of the registered ``method``; an unknown name is a usage error."""
    from ..methods.registry import METHODS, make_method

    if method not in METHODS:
        raise click.UsageError(f"unknown method {method!r}; choose from {', '.join(METHODS)} "
                               "(see `btel methods`).")
    return type(make_method(method))


def _check_value(method: str, name: str, value: Any, given: str) -> Any:
    """``value``, or a usage error in the words of ``given`` (as typed) when the constraints refuse it."""
    from ..core.paramdocs import describe_constraints

    constraints = getattr(_method_class(method), "_parameter_constraints", {}).get(name)
    if constraints is None or any(value is None if c is None else c.accepts(value) for c in constraints):
        return value
    raise click.UsageError(f"{given}: {method}'s {name} must be {describe_constraints(constraints)}.")


def _params_by_method(methods: list[str], param_texts: tuple[str, ...], *,
                      shortcuts: dict[str, tuple[str, Any]] | None = None,
                      added: tuple[str, ...] = ()) -> dict[str, dict[str, Any]]:
    """Each method's parameters, every name and value checked before anything is fitted.

    Layers, later ones overriding: ``shortcuts`` (parameter name → (option, value) of each named
    option given), ``--param NAME=VALUE`` (every method), ``--param METHOD:NAME=VALUE`` (that
    method). A shortcut and ``--param`` setting one name, a name given twice in one layer, a name a
    method does not have, or a value its constraints refuse, is a usage error — except that a method
    the run ``added`` itself (the unbudgeted reference) takes an every-method ``--param`` only where it
    has the parameter: the user never named it.
    """
    from ..evaluation.inputs import RUNTIME_PARAMS  # runtime flags: how a method runs, not what it computes

    shortcuts = shortcuts or {}
    layers: dict[str, dict[str, tuple[Any, str]]] = {"": {}}
    for text in param_texts:
        key, eq, raw = text.partition("=")
        target, _, name = key.strip().rpartition(":")
        if not eq or not name.isidentifier():
            raise click.UsageError(f"--param {text!r} is not NAME=VALUE (or METHOD:NAME=VALUE), "
                                   "e.g. feature_ratio=0.25.")
        if target and target not in methods:
            raise click.UsageError(f"--param {text!r} is for {target!r}, which is not a method of this run "
                                   f"({', '.join(methods)}).")
        layer = layers.setdefault(target, {})
        if name in layer:
            raise click.UsageError(f"--param sets {key.strip()} twice; give it once.")
        if name in shortcuts and name not in RUNTIME_PARAMS:  # a runtime flag yields to an explicit --param
            raise click.UsageError(f"{shortcuts[name][0]} and --param {key.strip()}=… both set {name}; "
                                   "give one of them.")
        layer[name] = (_param_value(raw), f"--param {text}")
    out: dict[str, dict[str, Any]] = {}
    for method in methods:
        valid = sorted(_method_class(method)._get_param_names())
        for name, (option, _) in shortcuts.items():
            if name not in valid and name not in RUNTIME_PARAMS:
                raise click.UsageError(f"{option} sets parameter {name!r}, which {method} does not have; "
                                       f"{method} takes: {', '.join(valid)}.")
        every = {n: v for n, v in layers[""].items() if method not in added or n in valid}
        given = {**every, **layers.get(method, {})}
        for name in given:
            if name not in valid:
                hint = (f" (--param {name}=… applies to every method; write METHOD:{name}=… for one)"
                        if name in layers[""] and len(methods) > 1 else "")
                raise click.UsageError(f"{method} has no parameter {name!r}{hint}; "
                                       f"{method} takes: {', '.join(valid)}.")
        # Runtime flags (--no-progress, --n-jobs) change how a method runs, not what it computes: they apply
        # where the method has the parameter and are ignored elsewhere, so one command line fits every method.
        typed = {n: (v, f"{o} {_param_text(v)}") for n, (o, v) in shortcuts.items() if n in valid}
        out[method] = {n: _check_value(method, n, v, text) for n, (v, text) in {**typed, **given}.items()}
    return out


@contextmanager
def _naming(method: str) -> Iterator[None]:
    """A bad parameter value found while building, fitting or evaluating ``method`` names the method
    (:func:`btel.evaluation.inputs.method_named`)."""
    from ..evaluation.inputs import method_named

    with method_named(method):
        yield


class ParamCommand(click.Command):
    """A command with ``--param NAME=VALUE``: ``--param n_regions 5`` (a space for the '=') leaves 5 as an
    extra argument, which click reports without naming the cause; the error then says how to write it."""

    def parse_args(self, ctx: click.Context, args: list[str]) -> list[str]:
        given = list(args)  # click consumes the list it parses
        try:
            return super().parse_args(ctx, args)
        except click.UsageError as exc:
            bare = [i for i, a in enumerate(given[:-1]) if a == "--param" and "=" not in given[i + 1]]
            if bare and "unexpected extra argument" in exc.message:
                name = given[bare[0] + 1]
                value = given[bare[0] + 2] if bare[0] + 2 < len(given) else "VALUE"
                exc.message += f"; --param takes KEY=VALUE (e.g. --param {name}={value})."
            raise
