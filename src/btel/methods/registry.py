"""Every localization method by name, and :func:`load` for the model files they save.

``make_method("btel-c", budget="500KB")`` builds an unfitted estimator. Adding a method is one
class (a :class:`btel.methods.base.PlaceLocalizer`) and one line in :data:`_ENTRIES` (its module, class,
fixed parameters and description); :data:`REGISTRY` is derived from it.

A method's module is imported when the method is first asked for (:func:`make_method`,
:func:`load`), not with the registry: loading an LSH model never imports BTEL's classifiers
(scikit-learn) or its segmentation (ruptures). :data:`REGISTRY`, :data:`METHODS` and
:data:`MODEL_CLASSES` import every method on first access.

A model file is untrusted input: :func:`load` reads only plain arrays and JSON
(:func:`btel.core.modelfile.load_arrays`), accepts only the classes registered here, restores only the
declared parameters (never runtime settings such as ``n_jobs``) after checking each against its
constraints, checks every array's shape and dtype against what the recorded state implies before
the method sees it, and raises :class:`~btel.exceptions.ModelFileError` for anything else.
"""

from __future__ import annotations

import importlib
import os
import sys
from functools import partial
from typing import TYPE_CHECKING, Any, Callable, NamedTuple

from .roles import DEFAULT_METHOD, DEMO_METHODS, REFERENCE_METHOD
from ..core.validation import Instance, check_params, read_state_int
from .base import PlaceLocalizer
from .auto.localizer import AutoLocalizer, calibration_table
from .baselines import _BASELINE_CLASSES
from ..exceptions import BTELError, InvalidParameterError, ModelFileError, ResourceLimitError
from ..core.frontend import FrontEnd
from ..core.limits import check_places
from ..core.fingerprint import read_fingerprint
from ..core.storage import budget_of
from ..core.modelfile import load_arrays

if TYPE_CHECKING:  # pragma: no cover - imported on first use (_model_class)
    from .baselines import PQLocalizer, RaBitQLocalizer
    from .btel.localizer import BTELocalizer, block_size_for_tolerance
    from .codes.estimator import CodeLocalizer
    from .ryth import RYTHLocalizer

__all__ = ["REGISTRY", "METHODS", "DESCRIPTIONS", "MODEL_CLASSES", "make_method", "method_names", "load",
           "DEFAULT_METHOD", "REFERENCE_METHOD", "DEMO_METHODS", "block_size_for_tolerance",
           "calibration_table"]


class _Entry(NamedTuple):
    """Where a registered method lives and what its name fixes."""

    module: str  #: the class's module, relative to btel.methods
    cls: str  #: the class's name (what a model file records)
    fixed: dict[str, Any]  #: parameters the name fixes (e.g. btel-r: 20 regions)
    description: str  #: one line (``btel methods``)


_BASELINE_DESCRIPTIONS: dict[str, str] = {
    "bruteforce": "exact nearest neighbour over every map descriptor (the unbudgeted reference)",
    "pq": "product quantisation (faiss), the most code bits that fit the budget",
    "opq": "optimised PQ: a learned rotation, then PQ (faiss)",
    "itq": "iterative quantisation to binary codes, Hamming search (faiss)",
    "lsh": "seeded sign random projections filling the budget (projection from the seed, 0 B), "
           "asymmetric scoring (projected query · ±1 codes) or Hamming",
    "seqslam": "SeqSLAM sequence matching over a uint8 map (uses the query sequence)",
}

_BTEL = ".btel.localizer", "BTELocalizer"
#: Every method: name → where it lives, what its name fixes and one line on it. Adding a method is one
#: class and one line here.
_ENTRIES: dict[str, _Entry] = {
    "btel-c": _Entry(*_BTEL, {"scheme": "compressed", "n_regions": 1},
                     "BTE-C: one linear classifier per bit of the place index, O(d log N) bytes (the paper)"),
    "btel-f": _Entry(*_BTEL, {"scheme": "full", "n_regions": 1},
                     "BTE-F: one classifier per tree node, O(N) bytes (the paper's foil)"),
    "btel-r": _Entry(*_BTEL, {"scheme": "compressed", "n_regions": 20},
                     "BTEL with 20 KTS regions, a region classifier and one BTE-C tree each"),
    "btel-auto": _Entry(*_BTEL, {"scheme": "compressed", "n_regions": "auto"},
                        "BTEL with the number of regions chosen by the KTS penalty"),
    "btel-codes": _Entry(".codes.estimator", "CodeLocalizer", {},
                         "BTEL beyond the binary index: K ≥ log2 N implicit output codes (periodic on "
                         "a route or an ordered map, random on independent places), ridge-fitted, 4-bit "
                         "weights, K and d' filling the budget"),
    "ryth": _Entry(".ryth", "RYTHLocalizer", {},
                   "RYTH: residues of the place index modulo co-prime periods (Yu et al. 2018)"),
    **{name: _Entry(".baselines" + module, cls, {}, _BASELINE_DESCRIPTIONS[name])
       for name, (cls, module) in _BASELINE_CLASSES.items()},
    "rabitq": _Entry(".baselines.rabitq", "RaBitQLocalizer", {},
                     "RaBitQ: seeded rotation (0 B), D dims × B bits + row factors, filling the budget"),
    "auto": _Entry(".auto.localizer", "AutoLocalizer", {},
                   "the method and front end chosen from the map and the budget (btel.methods.auto): output "
                   "codes on routes, brute force or LSH elsewhere; fit(X, calibration=(Q, truth)) chooses "
                   "on labelled queries"),
}

#: One line per method (``btel methods``).
DESCRIPTIONS: dict[str, str] = {name: entry.description for name, entry in _ENTRIES.items()}

#: Class name (as a model file records it) → its module, for :func:`load`.
_MODEL_MODULES: dict[str, str] = {entry.cls: entry.module for entry in _ENTRIES.values()}

#: auto picks among the registered methods: it is handed the registry (no import back from btel.methods.auto).
AutoLocalizer._registry = sys.modules[__name__]


def _model_class(name: str) -> type[PlaceLocalizer]:
    """The registered class recorded in a model file as ``name`` (its module imported now)."""
    return getattr(importlib.import_module(_MODEL_MODULES[name], __package__), name)


def _factory(name: str) -> Callable[..., PlaceLocalizer]:
    """The unfitted-estimator factory of a registered method (its class, or a partial fixing parameters)."""
    entry = _ENTRIES[name]
    cls = _model_class(entry.cls)
    return partial(cls, **entry.fixed) if entry.fixed else cls


def _every_method() -> dict[str, Any]:
    """The tables that import every method: REGISTRY, METHODS, MODEL_CLASSES."""
    registry = {name: (_factory(name), entry.description) for name, entry in _ENTRIES.items()}
    return {"REGISTRY": registry, "METHODS": {name: entry[0] for name, entry in registry.items()},
            "MODEL_CLASSES": {name: _model_class(name) for name in _MODEL_MODULES}}


def __getattr__(name: str) -> Any:
    """:data:`REGISTRY` (name → (factory, description)), :data:`METHODS` (name → factory) and
    :data:`MODEL_CLASSES` (class name → class), built on first access; ``block_size_for_tolerance``."""
    if name == "block_size_for_tolerance":
        return getattr(importlib.import_module(".btel.localizer", __package__), name)
    if name not in ("REGISTRY", "METHODS", "MODEL_CLASSES"):
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    globals().update(_every_method())
    return globals()[name]


def method_names() -> list[str]:
    """Registered method names, in registry order."""
    return list(_ENTRIES)


def make_method(name: str, **params: Any) -> PlaceLocalizer:
    """An unfitted method by registry name, with ``params`` overriding its defaults.

    Parameters
    ----------
    name : str
        A registered name: ``btel.methods.METHODS`` lists them (``btel methods`` on the command line), e.g.
        ``"auto"``, ``"btel-codes"``, ``"lsh"``, ``"pq"``, ``"bruteforce"``, ``"btel-c"``.
    **params
        Any of the method's parameters (``btel methods --params`` lists each one's range and
        meaning); ``budget`` (bytes, or a string such as ``"64KB"``) is the one most calls set.

    Returns
    -------
    PlaceLocalizer
        Unfitted; ``fit(X)`` with X of shape (N, d) makes it answer queries.

    Raises
    ------
    InvalidParameterError
        An unknown method name, an unknown parameter name or a value outside a parameter's declared
        range, at once (naming the method and the parameter).
    """
    if name not in _ENTRIES:
        raise InvalidParameterError(f"unknown method {name!r}; choose from {', '.join(_ENTRIES)}.")
    model = _factory(name)()
    valid = model._nested_param_names()
    unknown = sorted(set(params) - valid)
    if unknown:
        raise InvalidParameterError(
            f"{name} has no parameter {', '.join(repr(u) for u in unknown)}; it takes: {', '.join(sorted(valid))}."
        )
    model.set_params(**params)
    check_params(model)
    return model


def load(path: str | os.PathLike) -> PlaceLocalizer:
    """Load a model saved by ``save``; the class is read from the file's header.

    Raises
    ------
    ModelFileError
        Missing, corrupt, truncated, edited or foreign file, or an unknown model class. Nothing
        else escapes: any other failure while reading or checking the file becomes this error.
    UnsupportedModelVersionError
        A file from a newer btel.
    """
    arrays, header = load_arrays(path)
    where = repr(str(path))
    if header.get("kind") == "image-descriptor":
        raise ModelFileError(
            f"{where} is a saved image descriptor, not a localization model; "
            "load it with btel.descriptors.load_descriptor(path)."
        )
    name = header.get("model")
    cls = _model_class(name) if isinstance(name, str) and name in _MODEL_MODULES else None
    if cls is None:
        raise ModelFileError(f"{where} holds a model of unknown type {str(name)[:60]!r}; it was not written by this btel.")
    params, state = header.get("params"), header.get("state")
    if not isinstance(params, dict) or not isinstance(state, dict):
        raise ModelFileError(f"{where} has a corrupt header (params/state are not objects).")
    try:
        model = cls(**_params_from_file(cls, params))
        check_params(model)
        _restore(model, arrays, state)
        model.map_fingerprint_ = read_fingerprint(header.get("map"))
        budget = budget_of(model)
        if budget is not None and model.nbytes > budget:  # a fit never stores more than its budget
            raise ModelFileError(f"its arrays take {model.nbytes:,} B, over the budget of {budget:,} B its header "
                                 "records; the file is corrupt or was edited.")
    except ModelFileError as exc:
        raise ModelFileError(f"{where}: {exc}") from exc
    except ResourceLimitError as exc:  # N beyond the memory-tied ceiling: still a ModelFileError
        raise ModelFileError(f"{where}: {exc}") from None
    except BTELError as exc:
        raise ModelFileError(f"{where} is inconsistent with a {name} model: {exc}") from exc
    except Exception as exc:  # a file is untrusted input: whatever else goes wrong, it is a bad file
        raise ModelFileError(
            f"{where} is inconsistent with a {name} model ({type(exc).__name__}: {str(exc)[:200]}); "
            "the file is corrupt or was edited."
        ) from exc
    return model


def _params_from_file(cls: type[PlaceLocalizer], params: dict[str, Any]) -> dict[str, Any]:
    """The declared, non-runtime parameters of a header (a nested estimator rebuilt from its params).

    A parameter may hold an estimator only where its constraints declare one
    (:class:`~btel.core.validation.Instance`, e.g. OPQ's ``pq``), and only of that class.
    """
    declared = set(cls._parameter_constraints) - set(cls._runtime_params)
    unknown = sorted(set(params) - declared - set(cls._runtime_params))
    if unknown:
        raise ModelFileError(f"the model file has parameters {[u[:40] for u in unknown[:5]]} that {cls.__name__} "
                             "does not take.")
    out = {}
    for key in declared & set(params):
        value = params[key]
        if isinstance(value, dict):  # a nested estimator (OPQ's pq), saved as {"estimator", "params"}
            allowed = [c.cls for c in cls._parameter_constraints[key] if isinstance(c, Instance)]
            estimator = value.get("estimator")
            known = isinstance(estimator, str) and estimator in _MODEL_MODULES
            nested = _model_class(estimator) if known else None
            if nested is None or nested not in allowed or set(value) != {"estimator", "params"} \
                    or not isinstance(value["params"], dict):
                raise ModelFileError(f"the model file's parameter {key!r} is not a "
                                     f"{' or '.join(a.__name__ for a in allowed) or 'plain value'}.")
            value = nested(**_params_from_file(nested, value["params"]))
            check_params(value)
        out[key] = value
    return out


#: Most places a model file may declare: a place index fits in uint32.
#: A lower, memory-tied ceiling applies too: :func:`btel.core.limits.check_places` (``BTEL_MEMORY_LIMIT``).
MAX_PLACES = 2**32


def _restore(model: PlaceLocalizer, arrays: dict[str, Any], state: dict[str, Any]) -> None:
    """Check the common state, the front end and every array's shape and dtype; then restore."""
    n_places = read_state_int(state, "n_places", 2, MAX_PLACES)
    n_features = read_state_int(state, "n_features_in", 1, 2**31)
    arrays = dict(arrays)
    model.front_end_ = FrontEnd.restore(state.get("front_end"), arrays, n_features)
    specs = model._array_specs(state)
    unexpected = sorted(set(arrays) - set(specs))
    if unexpected:
        raise ModelFileError(f"the file holds arrays {[u[:40] for u in unexpected[:5]]} that a {type(model).__name__} "
                             "does not store.")
    for key, spec in specs.items():
        if key not in arrays:
            if spec.required:
                raise ModelFileError(f"the file lacks the array {key!r} ({spec.describe()}).")
            continue
        if not spec.matches(arrays[key]):
            a = arrays[key]
            raise ModelFileError(f"the file's array {key!r} has shape {a.shape} and dtype {a.dtype}; "
                                 f"expected {spec.describe()}.")
    check_places(n_places, f"a {type(model).__name__}")  # before anything sized by N is built
    model._restore(arrays, state)
    model.n_features_in_ = n_features
    fit_time = state.get("fit_time")
    model.fit_time_ = float(fit_time) if isinstance(fit_time, (int, float)) and not isinstance(fit_time, bool) \
        else float("nan")
    setattr(model, model._fitted_marker, n_places)  # the fitted marker: set last
