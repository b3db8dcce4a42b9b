"""The paper's sequence filter: inference only, O(a) memory, no stored bytes.

Window a. The filter keeps the last 2a outputs. A new prediction i is compared with the median m
of that history; if ``|i − m| > a + 1`` it is replaced by ``m + a + 1`` (the paper's rule, which
assumes forward motion), or clamped into ``[m − a − 1, m + a + 1]`` with ``mode='symmetric'``.
Nothing is corrected until the history holds 2a outputs. The history holds the raw predictions
(default) or the filtered ones (``history='filtered'``). The median of an even-sized history is
the mean of its two middle values, rounded down to a whole place.
"""

from __future__ import annotations

from collections import deque
from typing import Iterable

import numpy as np

from ..core.validation import check_positive_int
from ..exceptions import InvalidParameterError

__all__ = ["SequenceFilter", "filter_sequence"]

_MODES = ("forward", "symmetric")
#: Largest window a (the history holds 2a predictions).
MAX_WINDOW = 1 << 30
_HISTORIES = ("raw", "filtered")


class SequenceFilter:
    """Streaming sequence filter: feed predictions one by one with :meth:`update`.

    Parameters
    ----------
    window : int
        a ≥ 1; the history holds 2a outputs.
    mode : {'forward', 'symmetric'}
        'forward' replaces an outlier by m + a + 1 (the paper); 'symmetric' clamps to m ± (a + 1).
    history : {'raw', 'filtered'}
        Whether the history stores the incoming predictions or the filter's outputs.
    n_places : int, optional
        When given, corrected outputs are clipped to [0, N − 1].

    Examples
    --------
    >>> f = SequenceFilter(window=2)
    >>> [f.update(i) for i in [10, 11, 12, 13, 90, 15]]
    [10, 11, 12, 13, 14, 15]
    """

    def __init__(self, window: int, *, mode: str = "forward", history: str = "raw", n_places: int | None = None):
        self.window = check_positive_int(window, "window")
        if self.window > MAX_WINDOW:
            raise InvalidParameterError(f"window must be at most {MAX_WINDOW}; got {window!r}.")
        if mode not in _MODES:
            raise InvalidParameterError(f"mode must be one of {_MODES}; got {mode!r}.")
        if history not in _HISTORIES:
            raise InvalidParameterError(f"history must be one of {_HISTORIES}; got {history!r}.")
        self.mode = mode
        self.history = history
        self.n_places = None if n_places is None else check_positive_int(n_places, "n_places")
        self._past: deque[int] = deque(maxlen=2 * self.window)

    def reset(self) -> None:
        """Forget the history (e.g. after the robot is moved)."""
        self._past.clear()

    def update(self, prediction: int) -> int:
        """Filter one prediction and return the (possibly corrected) place index.

        Raises
        ------
        InvalidParameterError
            ``prediction`` is not a whole number ≥ 0 (and < N when ``n_places`` is given).
        """
        if isinstance(prediction, (int, np.integer)) and not isinstance(prediction, (bool, np.bool_)) \
                and 0 <= prediction < (self.n_places if self.n_places is not None else 2**63):
            return self._update(int(prediction))  # the usual case, checked without numpy
        return self._update(int(_check_predictions(np.asarray(prediction).reshape(1), self.n_places)[0]))

    def _update(self, raw: int) -> int:
        out = raw
        if len(self._past) == self._past.maxlen:
            median = int(np.floor(np.median(self._past)))
            reach = self.window + 1
            if abs(raw - median) > reach:
                if self.mode == "forward":
                    out = median + reach
                else:
                    out = int(np.clip(raw, median - reach, median + reach))
                if self.n_places is not None:
                    out = int(np.clip(out, 0, self.n_places - 1))
        self._past.append(raw if self.history == "raw" else out)
        return out


def filter_sequence(
    predictions: Iterable[int] | np.ndarray,
    window: int,
    *,
    mode: str = "forward",
    history: str = "raw",
    n_places: int | None = None,
) -> np.ndarray:
    """Apply :class:`SequenceFilter` to a whole sequence of predictions (in query order).

    Parameters
    ----------
    predictions : array-like of shape (n_queries,), int
        Place indices in query order (whole numbers, ≥ 0 and < ``n_places`` when given).
    window, mode, history, n_places
        As :class:`SequenceFilter`: the window a (queries), ``'forward'`` or ``'symmetric'``, the
        history the window reads (``'raw'`` predictions or the ``'filtered'`` ones), and N, which
        clips the output to [0, N).

    Returns
    -------
    ndarray of shape (n_queries,), int64
    """
    f = SequenceFilter(window, mode=mode, history=history, n_places=n_places)
    values = _check_predictions(np.asarray(predictions).ravel(), f.n_places)
    return np.fromiter((f._update(p) for p in values.tolist()), dtype=np.int64, count=values.size)


def _check_predictions(values: np.ndarray, n_places: int | None) -> np.ndarray:
    """Place indices as int64: whole, finite numbers in [0, N) (N = ``n_places``; no upper bound if None)."""
    if values.dtype.kind not in "biuf":
        raise InvalidParameterError(f"predictions must be place indices (whole numbers); got dtype {values.dtype}.")
    if values.dtype.kind == "f":
        if not np.isfinite(values).all() or not (values == np.round(values)).all():
            raise InvalidParameterError("predictions must be whole, finite place indices (no NaN or fractions).")
        if values.size and np.abs(values).max() >= 2.0**62:
            raise InvalidParameterError("predictions hold a place index beyond 2**62.")
    elif values.dtype.kind == "u" and values.size and int(values.max()) >= 2**63:
        raise InvalidParameterError("predictions hold a place index beyond 2**63.")
    out = values.astype(np.int64)
    if out.size and out.min() < 0:
        raise InvalidParameterError(f"predictions must be place indices ≥ 0; got {int(out.min())}.")
    if n_places is not None and out.size and out.max() >= n_places:
        raise InvalidParameterError(
            f"predictions must be place indices below N = {n_places}; got {int(out.max())}.")
    return out
