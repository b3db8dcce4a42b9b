"""btel: visual place recognition under a storage budget (binary tree encoding, BTEL).

>>> from btel import BTELocalizer, load
>>> from btel.datasets import synthetic_route
"""

from __future__ import annotations

from .base import PlaceLocalizer
from .codes import CodeLocalizer
from .localizer import BTELocalizer
from .methods import load, make_method
from .sequence import SequenceFilter, filter_sequence
from .storage import parse_budget

__version__ = "0.1.0"

__all__ = ["BTELocalizer", "CodeLocalizer", "PlaceLocalizer", "SequenceFilter", "filter_sequence", "load", "make_method", "parse_budget",
           "__version__"]
