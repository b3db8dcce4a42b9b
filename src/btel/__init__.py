"""btel: visual place recognition under a storage budget (binary tree encoding, BTEL).

>>> from btel import BTELocalizer, load
>>> from btel.datasets import synthetic_route

The public names below are imported on first use (PEP 562), so ``import btel`` and ``btel --help``
do not pay for scikit-learn and SciPy until a method is actually needed.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING

from ._lazy import lazy_names

__version__ = "0.1.0"

#: Public name → the submodule that defines it.
_LAZY = {
    "BTELocalizer": ".methods.btel.localizer",
    "CodeLocalizer": ".methods.codes.estimator",
    "PlaceLocalizer": ".methods.base",
    "SequenceFilter": ".sequence.filter",
    "filter_sequence": ".sequence.filter",
    "load": ".methods.registry",
    "make_method": ".methods.registry",
    "parse_budget": ".core.storage",
}

__all__ = ["BTELocalizer", "CodeLocalizer", "PlaceLocalizer", "SequenceFilter", "filter_sequence", "load", "make_method", "parse_budget",
           "__version__"]

if TYPE_CHECKING:  # pragma: no cover - for type checkers and IDEs only
    from .methods.base import PlaceLocalizer
    from .methods.codes.estimator import CodeLocalizer
    from .methods.btel.localizer import BTELocalizer
    from .methods.registry import load, make_method
    from .sequence.filter import SequenceFilter, filter_sequence
    from .core.storage import parse_budget


#: Subpackages reachable as attributes once ``import btel`` ran (``btel.datasets.synthetic_route``), imported then.
_SUBPACKAGES = ("datasets", "descriptors", "evaluation", "experiments", "methods", "sequence")

__getattr__, __dir__ = lazy_names(__name__, _LAZY, {
    name: (lambda name=name: importlib.import_module(f".{name}", __name__)) for name in _SUBPACKAGES})
