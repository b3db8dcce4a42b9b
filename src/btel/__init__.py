"""btel: visual place recognition under a storage budget (binary tree encoding, BTEL).

>>> from btel import BTELocalizer, load
>>> from btel.datasets import synthetic_route
"""

from __future__ import annotations

from .base import PlaceLocalizer, load
from .localizer import BTELocalizer
from .sequence import SequenceFilter, filter_sequence
from .storage import parse_budget

__version__ = "0.1.0"

__all__ = ["BTELocalizer", "PlaceLocalizer", "SequenceFilter", "filter_sequence", "load", "parse_budget", "__version__"]
