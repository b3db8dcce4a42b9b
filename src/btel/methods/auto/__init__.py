"""``auto``: the method, code family and front end chosen from the map and the budget alone.

=================== ==========================================================================
``rule.py``         the rule, its evidence and its known weak spots; :func:`choose_method`
``statistics.py``   the map statistics it reads: route share, route continuity, the birthday bound
``localizer.py``    :class:`AutoLocalizer`, the registered ``auto`` method: fits the first candidate
                    that fits the budget and records what it chose and why
=================== ==========================================================================
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from ..._lazy import lazy_names

if TYPE_CHECKING:  # pragma: no cover - imported on first use (btel._lazy)
    from .localizer import AutoLocalizer
    from .rule import (ORDER_BITS_FACTOR, SHRINK_LSH_BITS_PER_DIMENSION, SHRINK_LSH_BYTES_PER_PLACE,
                       SHRINK_LSH_MIN_RANK, choose_method)
    from .statistics import (CONTINUITY_GAPS, CONTINUITY_REFERENCE, ORDER_CONTINUITY, ROUTE_CONTINUITY,
                             ROUTE_SHARE, ROUTE_WINDOW, STAT_ROWS, IndexOrder, collision_bits, index_order,
                             map_cone_ratio, route_continuity, route_share)

__all__ = ["AutoLocalizer", "CONTINUITY_GAPS", "CONTINUITY_REFERENCE", "IndexOrder", "ORDER_BITS_FACTOR", "ORDER_CONTINUITY",
           "ROUTE_CONTINUITY", "ROUTE_SHARE", "ROUTE_WINDOW", "SHRINK_LSH_BITS_PER_DIMENSION",
           "SHRINK_LSH_BYTES_PER_PLACE", "SHRINK_LSH_MIN_RANK", "STAT_ROWS", "choose_method", "collision_bits",
           "index_order", "map_cone_ratio", "route_continuity", "route_share"]

_RULE = ("ORDER_BITS_FACTOR", "SHRINK_LSH_BITS_PER_DIMENSION", "SHRINK_LSH_BYTES_PER_PLACE",
         "SHRINK_LSH_MIN_RANK", "choose_method")
__getattr__, __dir__ = lazy_names(__name__, {"AutoLocalizer": ".localizer", **dict.fromkeys(_RULE, ".rule"),
                                             **{n: ".statistics" for n in __all__
                                                if n not in _RULE and n != "AutoLocalizer"}})
