"""Tolerance-aware codes: encode blocks of B consecutive places, answer the block's centre.

A user who accepts an error of t frames does not need the low bits of the place index: with
blocks of B consecutive places, a tree over the ⌈N/B⌉ block indices predicts a block and the
localizer answers its centre place, which lies within ⌈(B−1)/2⌉ ≤ t of every place of the block
when B ≤ 2t + 1. With B = 2^L this is dropping the L low bits of h(i) (``i >> L`` is the block).
The tree has ⌈log2 ⌈N/B⌉⌉ bits instead of ⌈log2 N⌉, so under the same byte budget each remaining
classifier gets more columns (d'): the budget fitting of :class:`~btel.localizer.BTELocalizer`
does that by itself, since the inner localizer is fitted with ``places = i // B``.

Default rule for ``tolerance=t`` (the issue's): B = 2^L with L the largest integer where
2^L ≤ t (B = 1 for t = 0), so the worst error inside a block, 2^(L−1), is at most t/2. Pass
``block_size`` for any other B (e.g. 2t + 1, the largest block whose centre is within t of all
its places).

:class:`TolerantLocalizer` wraps an unfitted BTELocalizer (like scikit-learn's meta-estimators:
``get_params(deep=True)`` exposes ``localizer__C`` etc.), so every option of BTEL applies to the
block tree.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np
from sklearn.base import clone

from ._validation import check_descriptors, check_is_fitted, check_places, check_positive_int
from .base import PlaceLocalizer
from .exceptions import InvalidParameterError, ModelFileError, NotEnoughPlacesError
from .localizer import BTELocalizer
from .ranking import place_costs, rank_places
from .storage import save_arrays

__all__ = ["TolerantLocalizer", "block_size_for_tolerance", "block_labels", "block_centres"]


def block_size_for_tolerance(tolerance: int) -> int:
    """B = 2^L, the largest power of two ≤ t (1 for t = 0): the issue's rule "drop L bits, 2^L ≤ t"."""
    t = check_positive_int(tolerance, "tolerance", minimum=0)
    return 1 if t == 0 else 1 << (t.bit_length() - 1)


def block_labels(places: np.ndarray, block_size: int) -> np.ndarray:
    """Block index of each place: ``places // B`` (int64)."""
    return np.asarray(places, dtype=np.int64) // check_positive_int(block_size, "block_size")


def block_centres(blocks: np.ndarray, block_size: int, n_places: int) -> np.ndarray:
    """Centre place of each block, ``(first + last) // 2`` (the last block may be shorter).

    Returns
    -------
    ndarray of the shape of ``blocks``, int64, values in [0, N)
    """
    B = check_positive_int(block_size, "block_size")
    first = np.asarray(blocks, dtype=np.int64) * B
    last = np.minimum(first + B, int(n_places)) - 1
    return (first + last) // 2


class TolerantLocalizer(PlaceLocalizer):
    """BTEL over blocks of B consecutive places, answering each block's centre place.

    Parameters
    ----------
    localizer : BTELocalizer, optional
        Unfitted template (cloned in fit) for the block tree: its budget, C, regions, decode…
        apply. None: ``BTELocalizer()``. Ranking and :meth:`place_scores` need
        ``scheme='compressed'``.
    block_size : int, optional
        B ≥ 1 places per block.
    tolerance : int, optional
        t ≥ 0 frames; sets B by :func:`block_size_for_tolerance` when ``block_size`` is None.
        With neither, B = 1 (plain BTEL).
    budget : int or str, optional
        Byte budget of the block tree; when given it replaces the localizer's own ``budget`` (so
        that a registry entry ``make_method(name, budget=...)`` works as for every method).
    n_regions_searched : int
        Regions searched by :meth:`rank` (see :func:`btel.ranking.rank_places`).
    region_weight : float
        α of the ranking and scoring rule across regions.

    Attributes
    ----------
    localizer_ : BTELocalizer
        The fitted block tree (its ``n_places_`` is the number of blocks).
    block_size_ : int
    n_blocks_ : int
    n_places_ : int
        N, places of the map.
    n_features_in_ : int

    Examples
    --------
    >>> from btel import BTELocalizer
    >>> from btel.datasets import synthetic_route
    >>> route = synthetic_route(n_places=500, dim=256, seed=0)
    >>> model = TolerantLocalizer(BTELocalizer(budget="20KB", progress=False), tolerance=4).fit(route.map)
    >>> model.block_size_, model.n_blocks_
    (4, 125)
    """

    supports_ranking = True

    def __init__(
        self,
        localizer: BTELocalizer | None = None,
        *,
        block_size: int | None = None,
        tolerance: int | None = None,
        budget: int | str | None = None,
        n_regions_searched: int = 1,
        region_weight: float = 1.0,
    ) -> None:
        self.localizer = localizer
        self.block_size = block_size
        self.tolerance = tolerance
        self.budget = budget
        self.n_regions_searched = n_regions_searched
        self.region_weight = region_weight

    def _block_size(self) -> int:
        if self.block_size is not None and self.tolerance is not None:
            raise InvalidParameterError("give block_size or tolerance, not both.")
        if self.block_size is not None:
            return check_positive_int(self.block_size, "block_size")
        if self.tolerance is not None:
            return block_size_for_tolerance(self.tolerance)
        return 1

    def fit(self, X: Any, places: Any = None) -> "TolerantLocalizer":
        """Fit the block tree on ``places // B``.

        Parameters
        ----------
        X : array-like of shape (n_samples, n_features)
            Map descriptors; row i is place i unless ``places`` is given.
        places : array-like of shape (n_samples,), int, optional
            Place of each row (must cover 0..N−1).

        Returns
        -------
        self : TolerantLocalizer
        """
        B = self._block_size()
        X = check_descriptors(X, name="X")
        if places is None:
            places_arr, n_places = np.arange(X.shape[0], dtype=np.int64), X.shape[0]
        else:
            places_arr, n_places = check_places(places, X.shape[0])
        n_blocks = -(-n_places // B)
        if n_blocks < 2:
            raise NotEnoughPlacesError(
                f"N = {n_places} places in blocks of {B} make {n_blocks} block: a tree needs at least 2. "
                "Use a smaller block_size / tolerance."
            )
        template = BTELocalizer() if self.localizer is None else self.localizer
        if not isinstance(template, BTELocalizer):
            raise InvalidParameterError(f"localizer must be a BTELocalizer; got {type(template).__name__}.")
        inner = clone(template)
        if self.budget is not None:
            inner.set_params(budget=self.budget)
        self.localizer_ = inner.fit(X, places=block_labels(places_arr, B))
        self.block_size_ = B
        self.n_blocks_ = n_blocks
        self.n_features_in_ = int(X.shape[1])
        self.n_places_ = int(n_places)
        return self

    # -- inference -----------------------------------------------------------------------------
    def predict(self, Q: Any) -> np.ndarray:
        """Centre place of each query's predicted block.

        Returns
        -------
        ndarray of shape (n_queries,), int64, values in [0, N)
        """
        check_is_fitted(self, "n_places_")
        return block_centres(self.localizer_.predict(Q), self.block_size_, self.n_places_)

    def decision_function(self, Q: Any) -> np.ndarray:
        """Bit margins of the block tree (see ``BTELocalizer.decision_function``)."""
        check_is_fitted(self, "n_places_")
        return self.localizer_.decision_function(Q)

    def rank(self, Q: Any, k: int = 10) -> np.ndarray:
        """Centres of the ``k`` best blocks per query, best first.

        Returns
        -------
        ndarray of shape (n_queries, min(k, n_blocks_)), int64
        """
        check_is_fitted(self, "n_places_")
        blocks, _ = rank_places(self.localizer_, Q, k, n_regions_searched=self.n_regions_searched,
                                region_weight=self.region_weight)
        return block_centres(blocks, self.block_size_, self.n_places_)

    def place_scores(self, Q: Any) -> np.ndarray:
        """Per-place scores for sequence decoding: minus the cost of the place's block.

        Returns
        -------
        ndarray of shape (n_queries, N), float64
        """
        check_is_fitted(self, "n_places_")
        costs = place_costs(self.localizer_, Q, region_weight=self.region_weight)
        return -costs[:, np.arange(self.n_places_) // self.block_size_]

    # -- storage and files ---------------------------------------------------------------------
    def _stored_arrays(self) -> dict[str, np.ndarray]:
        # B and N are header scalars, as N is for BTELocalizer.
        return self.localizer_._stored_arrays()

    def _fitted_state(self) -> dict[str, Any]:
        inner = {k: v for k, v in self.localizer_.get_params(deep=False).items()}
        return {
            "n_places": self.n_places_,
            "block_size": self.block_size_,
            "localizer_params": {k: (v if v is None or isinstance(v, (bool, int, float, str)) else str(v))
                                 for k, v in inner.items()},
            "localizer_state": self.localizer_._fitted_state(),
        }

    def _restore(self, arrays: dict[str, np.ndarray], state: dict[str, Any]) -> None:
        n_places, B = int(state["n_places"]), int(state["block_size"])
        if B < 1 or n_places < 2:
            raise ModelFileError("tolerant model header holds an invalid block size or number of places.")
        inner = BTELocalizer(**state.get("localizer_params", {}))
        inner._restore(arrays, state["localizer_state"])
        if inner.n_places_ != -(-n_places // B):
            raise ModelFileError(f"the block tree has {inner.n_places_} blocks; N = {n_places}, B = {B} needs "
                                 f"{-(-n_places // B)}.")
        self.localizer_ = inner
        self.block_size_ = B
        self.n_blocks_ = inner.n_places_
        self.n_features_in_ = inner.n_features_in_
        self.n_places_ = n_places

    def save(self, path: str | os.PathLike) -> Path:
        """Save the fitted model: the block tree's arrays plus a JSON header (no pickles).

        The inner localizer's parameters go into the header's state (an estimator is not JSON).
        """
        check_is_fitted(self, "n_places_")
        params = {k: v for k, v in self.get_params(deep=False).items() if k != "localizer"}
        header = {"model": type(self).__name__, "params": params, "state": self._fitted_state()}
        return save_arrays(path, self._stored_arrays(), header)
