"""btel-codes: K linear classifiers predict the columns of an N × K ±1 output code.

=================== ===========================================================================
module              what
=================== ===========================================================================
``estimator``       :class:`CodeLocalizer`, the estimator
``codebook``        code families (periodic for routes, random for independent places), seeded
``planning``        the budget planner: K columns, selected features, weight bits
``solvers``         liblinear / ridge fitting of the K columns
``quantise``        weight quantisation to the planned bits
``decoding``        the exact decode paths (dense, bounded, scan) and the coarse one
=================== ===========================================================================
"""

from __future__ import annotations

from .estimator import CodeLocalizer

__all__ = ["CodeLocalizer"]
