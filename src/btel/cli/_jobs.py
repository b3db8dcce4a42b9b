"""``--param`` values checked per method, and the run of ``demo`` / ``evaluate``: the command line's side.

The values are checked against each method's ``get_params()`` before anything is fitted; the jobs
are :func:`btel.evaluation.make_jobs`'s and the run is :func:`btel.evaluation.run_methods`, which
this module calls with the command line's echo, exit status and files (galleries, pairs).
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import click

from ._options import EXIT_INTERRUPTED, _command_line
from ._params import _param_value

def _valid_params(method: str) -> list[str]:
    """Parameter names of ``method`` (its ``get_params()`` keys), sorted; an unknown method is a usage error."""
    from ..methods.registry import METHODS, make_method
    if method not in METHODS:
        raise click.UsageError(f"unknown method {method!r}; choose from {', '.join(METHODS)} (see `btel methods`).")

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
    from ..evaluation.inputs import RUNTIME_PARAMS

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
        if name in shortcuts and name not in RUNTIME_PARAMS:  # a runtime flag yields to an explicit --param
            raise click.UsageError(f"{shortcuts[name][0]} and --param {key.strip()}=… both set {name}; give one of them.")
        layer[name] = _param_value(raw)
    out: dict[str, dict[str, Any]] = {}
    for method in methods:
        valid = _valid_params(method)
        for name, (option, _) in shortcuts.items():
            if name not in valid and name not in RUNTIME_PARAMS:
                raise click.UsageError(f"{option} sets parameter {name!r}, which {method} does not have; "
                                       f"{method} takes: {', '.join(valid)}.")
        given = {**general, **targeted.get(method, {})}
        for name in given:
            if name not in valid:
                hint = (f" (--param {name}=… applies to every method; write METHOD:{name}=… for one)"
                        if name in general and len(methods) > 1 else "")
                raise click.UsageError(f"{method} has no parameter {name!r}{hint}; {method} takes: {', '.join(valid)}.")
        # Runtime flags (--no-progress, --n-jobs) change how a method runs, not what it computes: they apply
        # where the method has the parameter and are ignored elsewhere, so one command line fits every method.
        applied = {n: v for n, (_, v) in shortcuts.items() if n in valid}
        out[method] = {**(base or {}).get(method, {}), **applied, **given}
    return out


@contextmanager
def _naming(method: str) -> Iterator[None]:
    """A bad parameter value of ``method`` names the method (:func:`btel.evaluation.batch.method_named`)."""
    from ..evaluation.inputs import method_named

    with method_named(method):
        yield


def _fit_jobs(names: list[str], budgets: list[str | None], param_texts: tuple[str, ...], *,
              reference: bool, shortcuts: dict[str, tuple[str, Any]] | None = None) -> list[Any]:
    """The jobs of ``--methods`` × ``--budget`` with their ``--param`` values (``make_jobs``)."""
    from ..evaluation.inputs import make_jobs
    from ..methods.registry import REFERENCE_METHOD

    checked = [*names, REFERENCE_METHOD] if reference and REFERENCE_METHOD not in names else names
    params = _params_by_method(checked, param_texts, shortcuts=shortcuts)
    return make_jobs(names, budgets, params, reference=reference)


def _run_jobs(jobs: list[Any], X: Any, Q: Any, *, out: Path, extra: dict[str, Any], progress: bool,
              pairs: tuple[dict[str, Path], list[str], list[str]] | None = None, **options: Any) -> bool:
    """:func:`btel.evaluation.run_methods` with the command line's echo (Ctrl-C: exit 130), then the
    galleries and ``--pairs`` files. True when some row did not run."""
    from ..evaluation.batch import run_methods
    from ._gallery import galleries_after_run

    try:
        results = run_methods(jobs, X, Q, out=out, extra=extra, progress=progress, command=_command_line(),
                              echo=click.echo, **options)
    except KeyboardInterrupt:
        raise click.exceptions.Exit(EXIT_INTERRUPTED) from None
    galleries_after_run(out, extra)
    if pairs is not None:
        from ._names import write_pairs

        targets, q_names, db_names = pairs
        for r in results:
            if r.name in targets and r.ok and r.ranked is not None:
                n = write_pairs(targets[r.name], r.ranked, q_names, db_names, overwrite=options["overwrite"])
                click.echo(f"pairs ({r.name}, top {r.ranked.shape[1]}): {n} lines in {targets[r.name]}")
    return any(not r.ok for r in results)
