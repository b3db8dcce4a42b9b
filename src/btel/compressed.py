"""Compressed training, BTE-C (SPEC §3): b independent bit classifiers over all N places.

Classifier k is trained on every descriptor with label bit k of h(place) (MSB first), on its own
d' columns (:func:`btel.feature_selection.select_features`). The b fits are independent and run in
parallel (:func:`btel.training.fit_tasks`). Storage: b·(d' weights + d' column indices + 1 bias),
i.e. O(log N); inference: one margin per bit, then the constrained (or soft) decode.

Limit: a linear classifier separates an arbitrary labelling of N points only when N ≲ d'+1.
The low bits alternate between neighbouring places, so with N ≫ d' they cannot be memorised and
accuracy rests on the high bits (long contiguous blocks of the route) being learnable.
"""

from __future__ import annotations

import numpy as np

from .encoding import decode_constrained, decode_soft, encode, n_bits_for
from .training import Task

__all__ = ["compressed_tasks", "compressed_n_classifiers", "decode_margins", "DECODERS"]

DECODERS = ("constrained", "soft")


def compressed_n_classifiers(n_places: int) -> int:
    """Hyperplanes BTE-C stores for N places: b = max(1, ceil(log2 N))."""
    return n_bits_for(n_places)


def compressed_tasks(places: np.ndarray, n_places: int, rows: np.ndarray | None = None) -> list[Task]:
    """The b bit classifiers of one BTE-C tree, MSB first.

    Parameters
    ----------
    places : ndarray of shape (n_rows,), int64
        Local place index of each training row, in [0, n_places).
    n_places : int
        N of this tree (≥ 2).
    rows : ndarray of shape (n_rows,), optional
        Rows of X these places belong to (None: all of X).
    """
    bits = encode(places, n_bits_for(n_places))
    return [Task(labels=bits[:, k], rows=rows) for k in range(bits.shape[1])]


def decode_margins(margins: np.ndarray, n_places: int, method: str = "constrained") -> np.ndarray:
    """Bit margins (n, b) → place indices (n,) int64 in [0, N), by the chosen decode."""
    if method == "soft":
        return decode_soft(margins, n_places)
    return decode_constrained(margins, n_places)
