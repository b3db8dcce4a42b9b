"""BTEL (Le, Hoang & Milford): b ≈ log2 N linear classifiers predict the bits of a place's index.

=================== ===========================================================================
module              what
=================== ===========================================================================
``localizer``       :class:`BTELocalizer`, the estimator (schemes BTE-C / BTE-F, regions)
``decoding``        inference: region, then the tree's code; every code ranked by cost
``model_file``      the stored arrays and header state, checked on load
``encoding``        place index ↔ bit code; constrained decoding to indices < N
``compressed``      BTE-C: one classifier per bit, decoded by sign or margin
``full``            BTE-F: every bit block's full code table
``planning``        the budget planner: largest (bits, features, regions) that fits
``ranking``         candidate places ranked by code distance
``regions``         BTE-R: KTS segments plus a region classifier
``segmentation``    kernel temporal segmentation (ruptures) and region lookup
``diagnostics``     per-bit accuracy and error analysis of a fitted model
=================== ===========================================================================
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from ..._lazy import lazy_names

__all__ = ["BTELocalizer"]

if TYPE_CHECKING:  # pragma: no cover - imported on first use (btel._lazy)
    from .localizer import BTELocalizer

__getattr__, __dir__ = lazy_names(__name__, {"BTELocalizer": ".localizer"})
