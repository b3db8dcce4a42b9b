"""Every localization method by name: BTEL variants and the baselines, one interface.

``make_method("btel-c", budget="500KB")`` builds an unfitted estimator. Adding a method is one
class (a :class:`btel.base.PlaceLocalizer`) and one line here.
"""

from __future__ import annotations

from functools import partial
from typing import Any, Callable

from .baselines import BASELINES
from .base import PlaceLocalizer
from .exceptions import InvalidParameterError
from .localizer import BTELocalizer
from .ryth import RYTHLocalizer

__all__ = ["METHODS", "make_method", "method_names"]

METHODS: dict[str, Callable[..., PlaceLocalizer]] = {
    "btel-c": partial(BTELocalizer, scheme="compressed", n_regions=1),
    "btel-f": partial(BTELocalizer, scheme="full", n_regions=1),
    "btel-r": partial(BTELocalizer, scheme="compressed", n_regions=20),
    "btel-auto": partial(BTELocalizer, scheme="compressed", n_regions="auto"),
    "ryth": RYTHLocalizer,
    **BASELINES,
}


def method_names() -> list[str]:
    """Registered method names, in registry order."""
    return list(METHODS)


def make_method(name: str, **params: Any) -> PlaceLocalizer:
    """An unfitted method by registry name, with ``params`` overriding its defaults."""
    if name not in METHODS:
        raise InvalidParameterError(f"unknown method {name!r}; choose from {', '.join(METHODS)}.")
    return METHODS[name](**params)
