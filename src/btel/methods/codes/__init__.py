"""btel-codes: K linear classifiers predict the columns of an N × K ±1 output code.

=================== ===========================================================================
module              what
=================== ===========================================================================
``estimator``       :class:`CodeLocalizer`, the estimator
``codebook``        code families (periodic for routes, random for independent places), seeded
``hashing``         the seeded hashes behind the codebooks; the random family's generation rules
``planning``        the budget planner: K columns, selected features, weight bits
``solvers``         liblinear / ridge fitting of the K columns
``quantise``        weight quantisation to the planned bits
``decoding``        the bounded exact search over blocks and the rule choosing a decode path
``codewords``       the codebook at inference (dense / packed codewords, faiss scan); coarse to fine
``model_file``      the stored arrays and header state, checked on load
=================== ===========================================================================
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from ..._lazy import lazy_names

__all__ = ["CodeLocalizer"]

if TYPE_CHECKING:  # pragma: no cover - imported on first use (btel._lazy)
    from .estimator import CodeLocalizer

__getattr__, __dir__ = lazy_names(__name__, {"CodeLocalizer": ".estimator"})
