"""Every localization method, one folder or file per family, behind one interface.

====================== ========================================================================
where                  what
====================== ========================================================================
``methods/btel/``      BTEL: BTE-C (compressed codes), BTE-F (full codes), regions (BTE-R),
                       the bit encoding, ranking by code distance, and the budget planner
``methods/codes/``     btel-codes: output codes (periodic/random codebooks), their planner,
                       solvers, weight quantisation and decoding
``methods/ryth.py``    RYTH: one-vs-rest linear classifiers (the paper's N-classifier baseline)
``methods/auto/``      ``auto``: chooses a method and front end from the map and budget alone
``methods/baselines/`` brute force, PQ, OPQ, ITQ, LSH, RaBitQ, SeqSLAM
``registry.py``        ``{name: (factory, description)}``, :func:`make_method`, :func:`load`
====================== ========================================================================

Each method answers for its own bytes (its planner, ``check_budget``, its stored arrays), so the
shared layers never ask which class a method is. Adding a method is one file or folder here and
one line in :data:`btel.methods.registry.REGISTRY`.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from .._lazy import lazy_names

# The registry is imported on first use (the CLI's help needs none of it).
if TYPE_CHECKING:  # pragma: no cover
    from .registry import DESCRIPTIONS, METHODS, MODEL_CLASSES, REGISTRY, load, make_method, method_names

__all__ = ["DESCRIPTIONS", "METHODS", "MODEL_CLASSES", "REGISTRY", "load", "make_method", "method_names"]

__getattr__, __dir__ = lazy_names(__name__, dict.fromkeys(__all__, ".registry"))
