"""BTEL inference: a query's region, then its tree's code, and every other code ranked by cost.

:class:`TreeDecoding` holds what :class:`~btel.methods.btel.localizer.BTELocalizer` does with a
query once fitted. With r regions the region classifier picks the tree (:mod:`btel.methods.btel.regions`);
the tree's margins are decoded to a code — by sign with the constrained MSB-first rule or softly
(:mod:`btel.methods.btel.compressed`), node by node for BTE-F (:mod:`btel.methods.btel.full`). A code
is a block of ``block_size`` consecutive places (one place when block_size = 1) and answers its
block's centre (:func:`block_centres`). Ranking (:mod:`btel.methods.btel.ranking`) orders the other
codes by the cost of the bit flips that reach them plus the region classifier's deficit.
"""

from __future__ import annotations

import numpy as np

from ..base import put_first, top_k
from .compressed import compressed_code, decode_code, decode_margins
from .encoding import _decode_constrained, n_bits_for
from .full import full_costs, predict_full
from .ranking import code_costs, deficits_from_scores, merge_region_kbest
from .regions import predict_regions

__all__ = ["TreeDecoding", "block_centres"]


def block_centres(codes: np.ndarray, block_size: int, n_places: int) -> np.ndarray:
    """Centre place of each block of ``block_size`` consecutive places (the last may be shorter).

    Returns
    -------
    ndarray of the shape of ``codes``, int64, in [0, N)
    """
    first = np.asarray(codes, dtype=np.int64) * int(block_size)
    last = np.minimum(first + int(block_size), int(n_places)) - 1
    return (first + last) // 2


class TreeDecoding:
    """Inference of a fitted BTEL model (mixed into :class:`~btel.methods.btel.localizer.BTELocalizer`).

    Reads the fitted attributes ``hyperplanes_``, ``region_hyperplanes_``, ``tree_offsets_``,
    ``region_starts_``, ``region_sizes_``, ``n_blocks_``, ``n_regions_``, ``block_size_``,
    ``code_copies_`` and the parameters ``scheme`` and ``decode``.
    """

    def _region_scores(self, Q: np.ndarray) -> np.ndarray | None:
        return None if self.n_regions_ == 1 else self.region_hyperplanes_.margins(Q)

    def _tree_decode(self, Q: np.ndarray, region: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(local codes, column margins, tree costs of those codes) of queries Q under one region's tree."""
        n_k = int(self.region_sizes_[region])
        first = int(self.tree_offsets_[region])
        if self.scheme == "full":
            codes, margins = predict_full(Q, self.hyperplanes_, first, n_k)
            return codes, margins, np.zeros(Q.shape[0])  # the greedy leaf follows every sign: cost 0
        rows = slice(first, int(self.tree_offsets_[region + 1]))
        margins = self.hyperplanes_.margins(Q, rows if self.n_regions_ > 1 else None)
        if self.code_copies_ > 1:
            codes = decode_code(margins, n_k, self.code_copies_)
        else:
            codes = decode_margins(margins, n_k, self.decode)
        return codes, margins, self._flip_costs(margins, codes, n_k)

    def _flip_costs(self, margins: np.ndarray, codes: np.ndarray, n_k: int) -> np.ndarray:
        """Cost ``Σ|m| − Σ m·sign(code)`` of one code per query (0 for the hard code)."""
        if n_k == 1:
            return np.zeros(margins.shape[0])
        levels, shifts = compressed_code(n_k, self.code_copies_)
        b = n_bits_for(n_k)
        shifted = codes[:, None] if self.code_copies_ == 1 else (codes[:, None] + shifts[None, :]) & ((1 << b) - 1)
        bits = ((shifted >> (b - 1 - levels)[None, :]) & 1).astype(bool)
        # A column costs 2|m| where the code's bit disagrees with the margin's sign, else nothing.
        flipped = bits != (margins > 0)
        return 2.0 * np.einsum("ij,ij->i", np.abs(margins, dtype=np.float64), flipped, dtype=np.float64)

    def _decode(self, Q: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(codes, margins padded to the widest tree, cost) of each query: region, then its tree."""
        if self.n_regions_ == 1:  # one tree over all codes: its local codes are global
            return self._tree_decode(Q, 0)
        regions = predict_regions(self._region_scores(Q), self.n_regions_, Q.shape[0])
        codes = np.empty(Q.shape[0], dtype=np.int64)
        costs = np.empty(Q.shape[0])
        margins = np.full((Q.shape[0], self._tree_width), np.nan, dtype=np.float32)
        present = np.unique(regions) if Q.shape[0] > 1 else regions
        for k in present:
            rows = slice(None) if present.size == 1 else np.flatnonzero(regions == k)
            local, m, cost = self._tree_decode(Q[rows], int(k))
            codes[rows] = self.region_starts_[k] + local
            margins[rows, : m.shape[1]] = m
            costs[rows] = cost  # the predicted region's deficit is 0
        return codes, margins, costs

    def _predict(self, Q: np.ndarray) -> np.ndarray:
        """The decode alone (no scores): what ``_search(Q, 1)`` answers, without the flip costs."""
        if self.n_regions_ == 1 and self.scheme == "compressed":
            margins = self.hyperplanes_.margins(Q)
            n_k = int(self.region_sizes_[0])
            if self.code_copies_ > 1:
                codes = decode_code(margins, n_k, self.code_copies_)
            elif self.decode == "constrained":  # the hot path (streaming, batches): margins are ours
                codes = _decode_constrained(margins, n_k)
            else:
                codes = decode_margins(margins, n_k, self.decode)
            return self._places_of_codes(codes)
        return self._places_of_codes(self._decode(Q)[0])

    def _places_of_codes(self, codes: np.ndarray) -> np.ndarray:
        """Place answered for each code: the code itself, or its block's centre (block_size > 1)."""
        if self.block_size_ == 1:
            return codes
        return block_centres(codes, self.block_size_, self.n_places_)

    def _code_costs(self, Q: np.ndarray, region_weight: float = 1.0) -> np.ndarray:
        """Cost of every code (n_queries, n_blocks): tree cost + region_weight × region deficit."""
        margins = self.hyperplanes_.margins(Q).astype(np.float64)  # every tree's columns: one product
        deficits = deficits_from_scores(self._region_scores(Q), self.n_regions_, Q.shape[0])
        if self.scheme == "full":
            out = np.empty((Q.shape[0], self.n_blocks_))
            for k, (s, n_k) in enumerate(zip(self.region_starts_.tolist(), self.region_sizes_.tolist())):
                tree = full_costs(margins[:, self.tree_offsets_[k] : self.tree_offsets_[k + 1]], n_k)
                out[:, s : s + n_k] = tree + region_weight * deficits[:, k : k + 1]
            return out
        return code_costs(margins, deficits, self.region_starts_, self.region_sizes_, self.tree_offsets_,
                          code_copies=self.code_copies_, region_weight=region_weight)

    def _place_scores(self, Q: np.ndarray) -> np.ndarray:
        """−cost of every place (tree flip cost + region deficit; a block's places share its cost)."""
        scores = self._code_costs(Q)
        np.negative(scores, out=scores)  # in place: one (n, N) float64 array, not two
        if self.block_size_ > 1:  # every place scores what its block scores
            scores = scores[:, np.arange(int(self.n_places_)) // self.block_size_]
        return scores

    def _search(self, Q: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
        """The decode, then the other codes by cost (lowest first), as places (distinct block centres).

        The first candidate is always the decode (``predict``): with ``decode='constrained'`` a
        hard code ≥ N is mapped to a valid one by the paper's MSB-first rule, which need not be the
        cheapest valid code, so the ranking by cost follows it.
        """
        point, _, point_costs = self._decode(Q)
        if k == 1:
            return -point_costs[:, None], self._places_of_codes(point)[:, None]
        k_codes = min(k, self.n_blocks_)
        if self.scheme == "compressed" and self.code_copies_ == 1:
            margins = self.hyperplanes_.margins(Q).astype(np.float64)
            deficits = deficits_from_scores(self._region_scores(Q), self.n_regions_, Q.shape[0])
            codes, costs = merge_region_kbest(margins, deficits, self.region_starts_, self.region_sizes_,
                                              self.tree_offsets_, k_codes)
        else:  # offset codes and BTE-F: every code's cost (O(N·K) per query)
            neg, codes = top_k(-self._code_costs(Q), k_codes)
            costs = -neg
        scores, codes = put_first(-costs, codes, -point_costs, point)
        return scores, self._places_of_codes(codes)
