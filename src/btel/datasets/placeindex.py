"""Place indices read from untrusted arrays (predictions, true places, positives): whole numbers in int64,
never wrapped by a cast. Used by :mod:`btel.datasets.groundtruth`, which re-exports :func:`check_predictions`."""

from __future__ import annotations

from typing import Any

import numpy as np

from ..exceptions import InvalidParameterError

__all__ = ["check_predictions"]


def check_predictions(predictions: Any, n_queries: int, *, name: str = "predictions") -> np.ndarray:
    """Predicted place indices checked: ndarray of shape (n_queries,), int64 (one entry per query row)."""
    arr = np.asarray(predictions)
    if arr.ndim != 1 or arr.shape[0] != n_queries:
        raise InvalidParameterError(
            f"{name} must be 1-D with one place index per query ({n_queries}); got shape {arr.shape}."
        )
    return _as_int(arr, name)


def _as_int(arr: np.ndarray, name: str) -> np.ndarray:
    """``arr`` as int64 place indices: floats must be whole, other dtypes integers, none ≥ 2⁶² (``name`` in the
    messages)."""
    if arr.size and arr.dtype.kind == "f":
        if not np.all(np.isfinite(arr)) or not np.all(arr == np.round(arr)):
            raise InvalidParameterError(f"{name} must hold whole numbers (place indices).")
    elif arr.size and arr.dtype.kind not in "iu":
        raise InvalidParameterError(f"{name} must hold integer place indices; got dtype {arr.dtype}.")
    # A cast wraps (2⁶⁴−1 → −1); the top compared as a Python number (2⁶² overflows float16 and float32).
    if arr.size and arr.dtype.kind in "uf" and (top := arr.max().item()) >= 2.0 ** 62:
        raise InvalidParameterError(f"{name} holds {int(top) if arr.dtype.kind == 'u' else f'{top:g}'}, not a "
                                    "place index of any map.")
    return arr.astype(np.int64)
