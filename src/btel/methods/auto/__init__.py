"""``auto``: the method, code family and front end chosen from the map and the budget alone.

=================== ==========================================================================
``rule.py``         the map-only rule (evidence: docs/decisions/auto-rule.md); :func:`choose_method`
``calibrate.py``    the calibrated choice: every candidate scored on labelled queries, paired tests
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
    from .calibrate import calibration_candidates, choose_calibrated, mcnemar_exact
    from .rule import CODES_PLACES_PER_DIMENSION, ORDER_BITS_FACTOR, choose_method, front_end_variant
    from .statistics import (CONTINUITY_GAPS, CONTINUITY_REFERENCE, ORDER_CONTINUITY, ROUTE_CONTINUITY,
                             ROUTE_SHARE, ROUTE_WINDOW, STAT_ROWS, IndexOrder, collision_bits, index_order,
                             map_cone_ratio, route_continuity, route_share)

__all__ = ["AutoLocalizer", "CODES_PLACES_PER_DIMENSION", "CONTINUITY_GAPS", "CONTINUITY_REFERENCE", "IndexOrder",
           "ORDER_BITS_FACTOR", "ORDER_CONTINUITY", "ROUTE_CONTINUITY", "ROUTE_SHARE", "ROUTE_WINDOW",
           "STAT_ROWS",
           "calibration_candidates", "choose_calibrated", "choose_method",
           "collision_bits", "front_end_variant", "index_order", "map_cone_ratio", "mcnemar_exact",
           "route_continuity", "route_share"]

_RULE = ("CODES_PLACES_PER_DIMENSION", "ORDER_BITS_FACTOR", "choose_method", "front_end_variant")
_CALIBRATE = ("calibration_candidates", "choose_calibrated", "mcnemar_exact")
__getattr__, __dir__ = lazy_names(__name__, {"AutoLocalizer": ".localizer", **dict.fromkeys(_RULE, ".rule"),
                                             **dict.fromkeys(_CALIBRATE, ".calibrate"),
                                             **{n: ".statistics" for n in __all__
                                                if n not in _RULE + _CALIBRATE and n != "AutoLocalizer"}})
