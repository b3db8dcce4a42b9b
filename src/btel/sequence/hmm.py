"""Sequence decoding over places: an online HMM filter for any per-place score matrix.

The robot moves forward along the mapped route; a query stream is decoded by a hidden Markov model
whose states are the N places:

- **emissions**: ``log p(query_t | place i) = score_t[i] / T`` for any method's per-place scores
  (higher = more likely; :meth:`btel.methods.base.PlaceLocalizer.place_scores`): BTEL's minus flip costs,
  negative ADC distances of PQ/OPQ, negative Hamming distances of ITQ, negative squared L2 of brute
  force, z-scored per frame (:func:`emission_scores`) — so every method gets the same decoding;
- **transitions**: from place i to i + v, v ∈ {vmin … vmax} equally likely (forward motion), plus
  an optional ``backward`` probability spread over i − 1 … i − vmax, plus a ``teleport``
  probability spread over all N places (relocalisation after a wrong turn or a kidnapping).
  Probability that would leave the route past its end is dropped (the belief is renormalised).

:class:`HMMDecoder` is causal and streaming — ``update(scores) -> place`` — with O(N·V) work and
O(N) memory per query (V = number of offsets) and no stored bytes. ``mode='forward'`` outputs the
argmax of the filtered posterior p(place_t | queries_≤t); ``mode='viterbi'`` the end of the most
likely path so far (max-product). :func:`decode_sequence` runs it over a whole score matrix.

Compare with the paper's median filter (:func:`btel.sequence.filter_sequence`), which sees only
each frame's single prediction, and with SeqSLAM's straight-line search
(:func:`btel.methods.baselines.seqslam_match`), which needs the whole difference matrix of the last ds
frames (O(N·ds) memory).
"""

from __future__ import annotations

import numbers
from typing import Any

import numpy as np

from ..core.limits import check_places
from ..core.validation import check_is_fitted, check_positive_int
from ..exceptions import InvalidParameterError

__all__ = ["HMMDecoder", "HMM_OPTIONS", "decode_sequence", "zscore_rows", "emission_scores", "transition_kernel",
           "MODES"]

MODES = ("forward", "viterbi")
#: Options of :class:`HMMDecoder` besides N (what ``predict_sequence(Q, "hmm", **options)`` takes).
HMM_OPTIONS = ("temperature", "vmin", "vmax", "backward", "teleport", "mode")


def _check_probability(value: Any, name: str, *, upper_open: bool = True) -> float:
    if isinstance(value, bool) or not isinstance(value, numbers.Real) or not np.isfinite(value):
        raise InvalidParameterError(f"{name} must be a number in [0, 1); got {value!r}.")
    if not 0 <= value < 1:
        raise InvalidParameterError(f"{name} must be in [0, 1); got {value!r}.")
    return float(value)


def transition_kernel(vmin: int = 0, vmax: int = 2, backward: float = 0.0,
                      n_places: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Place offsets a step can make and their probabilities (before the teleport share).

    Parameters
    ----------
    vmin, vmax : int
        Forward offsets vmin … vmax (0 ≤ vmin ≤ vmax), equally likely.
    backward : float in [0, 1)
        Probability of a backward offset −1 … −max(vmax, 1), equally likely.
    n_places : int, optional
        N: offsets of N places or more land nowhere on the route and are left out (their
        probability is not given to the others), so a vmax far beyond N costs nothing.

    Returns
    -------
    offsets : ndarray of shape (V,), int64
    weights : ndarray of shape (V,), float64, summing to 1 (less when offsets were left out)
    """
    vmin = check_positive_int(vmin, "vmin", minimum=0)
    vmax = check_positive_int(vmax, "vmax", minimum=0)
    if vmax < vmin:
        raise InvalidParameterError(f"vmax must be ≥ vmin; got vmin={vmin}, vmax={vmax}.")
    backward = _check_probability(backward, "backward")
    reach = vmax if n_places is None else min(vmax, check_positive_int(n_places, "n_places") - 1)
    forward = np.arange(vmin, reach + 1, dtype=np.int64)  # empty when vmin ≥ N
    weights = np.full(forward.size, (1.0 - backward) / (vmax - vmin + 1))
    if backward > 0:
        back = -np.arange(1, min(max(vmax, 1), max(reach, 1)) + 1, dtype=np.int64)
        forward = np.concatenate([forward, back])
        weights = np.concatenate([weights, np.full(back.size, backward / max(vmax, 1))])
    return forward, weights


class HMMDecoder:
    """Streaming HMM filter over N places: feed one per-place score vector per query.

    Parameters
    ----------
    n_places : int
        N.
    temperature : float > 0
        T: emission log-likelihood = score / T. Smaller trusts each frame more.
    vmin, vmax : int
        Forward motion per query, in places.
    backward : float in [0, 1)
        Probability of moving back 1 … vmax places.
    teleport : float in [0, 1)
        Probability of jumping anywhere (uniform); > 0 lets the filter recover from a wrong lock.
    mode : {'forward', 'viterbi'}
        Filtered posterior (sum-product) or the best path's end (max-product).

    Examples
    --------
    >>> import numpy as np
    >>> dec = HMMDecoder(5, temperature=1.0, vmax=1)
    >>> [dec.update(np.eye(5)[i] * 3) for i in range(5)]
    [0, 1, 2, 3, 4]
    """

    def __init__(
        self,
        n_places: int,
        *,
        temperature: float = 1.0,
        vmin: int = 0,
        vmax: int = 2,
        backward: float = 0.0,
        teleport: float = 1e-3,
        mode: str = "forward",
    ) -> None:
        self.n_places = check_positive_int(n_places, "n_places")
        check_places(self.n_places, "the HMM decoder")
        if isinstance(temperature, bool) or not isinstance(temperature, numbers.Real) \
                or not np.isfinite(temperature) or temperature <= 0:
            raise InvalidParameterError(f"temperature must be a positive number; got {temperature!r}.")
        if mode not in MODES:
            raise InvalidParameterError(f"mode must be one of {MODES}; got {mode!r}.")
        self.temperature = float(temperature)
        self.teleport = _check_probability(teleport, "teleport")
        self.offsets, self.weights = transition_kernel(vmin, vmax, backward, self.n_places)
        self.mode = mode
        # Max-product: the exact log transition probability of an offset move includes the
        # teleport share that also lands there.
        self._log_weights = np.log((1.0 - self.teleport) * self.weights + self.teleport / self.n_places)
        self._belief: np.ndarray | None = None

    def reset(self) -> None:
        """Forget the past (start of a new run, or after the robot was moved)."""
        self._belief = None

    @property
    def belief(self) -> np.ndarray | None:
        """Current state over places, shape (N,), float64: the posterior (forward mode, sums to 1)
        or the best path's log-score minus its maximum (Viterbi); None before the first update."""
        return None if self._belief is None else self._belief.copy()

    def _check_scores(self, scores: Any) -> np.ndarray:
        s = np.asarray(scores, dtype=np.float64)
        if s.shape != (self.n_places,):
            raise InvalidParameterError(f"scores must have shape ({self.n_places},) (one per place); got {s.shape}.")
        if not np.isfinite(s).all():
            raise InvalidParameterError(
                "scores contain NaN or infinite values: for a model's scores, its weights are out of range for "
                "these descriptors (a damaged or foreign model file, or queries on another scale than the map). "
                "Refit the model or check the file with `btel info`."
            )
        return s

    def _shifted(self, values: np.ndarray, combine: str) -> np.ndarray:
        """Σ_o w_o·values[i − o] (forward) or max_o (values[i − o] + log w_o) (Viterbi), per place i."""
        n = self.n_places
        viterbi = combine == "max"
        out = np.full(n, -np.inf) if viterbi else np.zeros(n)
        work = np.empty(n)  # one workspace for every offset: N floats, not one temporary per offset
        weights = self._log_weights if viterbi else self.weights
        for o, w in zip(self.offsets.tolist(), weights.tolist()):
            if abs(o) >= n:  # a step longer than the route lands nowhere
                continue
            dst = out[o:] if o >= 0 else out[: n + o]
            src = values[: n - o] if o >= 0 else values[-o:]
            moved = work[: src.size]
            if viterbi:
                np.maximum(dst, np.add(src, w, out=moved), out=dst)
            else:
                dst += np.multiply(src, w, out=moved)
        return out

    def update(self, scores: Any) -> int:
        """Take one query's per-place scores (shape (N,), higher = better); return the place."""
        s = self._check_scores(scores)
        # Every step in place on N-float arrays (a map of millions of places: 8 MB a million each).
        log_e = np.subtract(s, s.max())
        log_e /= self.temperature
        if self.mode == "forward":
            emission = np.exp(log_e, out=log_e)
            if self._belief is None:
                post = emission * (1.0 / self.n_places)  # the uniform prior
            else:
                post = self._shifted(self._belief, "sum")
                total = post.sum()
                if total > 0:
                    post /= total
                else:
                    post.fill(1.0 / self.n_places)
                post *= 1.0 - self.teleport  # the prior: the moved belief plus the teleport share
                post += self.teleport / self.n_places
                post *= emission
            total = post.sum()
            # Every place impossible (no teleport, a belief that left the route): start afresh.
            if total > 0:
                post /= total
            else:
                post = np.divide(emission, emission.sum(), out=emission)
            self._belief = post
        else:
            if self._belief is None:
                delta = log_e
            else:
                moved = self._shifted(self._belief, "max")
                if self.teleport > 0:
                    np.maximum(moved, np.log(self.teleport / self.n_places) + self._belief.max(), out=moved)
                delta = np.add(moved, log_e, out=moved)
                if not np.isfinite(delta.max()):
                    delta = log_e
            delta -= delta.max()
            self._belief = delta
        return int(np.argmax(self._belief))


def decode_sequence(
    scores: Any,
    *,
    temperature: float = 1.0,
    vmin: int = 0,
    vmax: int = 2,
    backward: float = 0.0,
    teleport: float = 1e-3,
    mode: str = "forward",
    resets: Any = None,
) -> np.ndarray:
    """Run :class:`HMMDecoder` over consecutive queries (rows of ``scores``, in travel order).

    Parameters
    ----------
    scores : array-like of shape (n_queries, N)
        Per-place scores, higher = more likely (e.g. ``-btel.methods.btel.ranking.place_costs(model, Q)``).
    temperature, vmin, vmax, backward, teleport, mode
        As in :class:`HMMDecoder`.
    resets : array-like of int, optional
        Query rows at which the decoder forgets its past (the start of separate runs).

    Returns
    -------
    ndarray of shape (n_queries,), int64, values in [0, N)
    """
    S = np.asarray(scores)
    if S.ndim != 2 or S.shape[0] == 0:
        raise InvalidParameterError(f"scores must be a non-empty 2-D array (n_queries, N); got shape {S.shape}.")
    decoder = HMMDecoder(S.shape[1], temperature=temperature, vmin=vmin, vmax=vmax, backward=backward,
                         teleport=teleport, mode=mode)
    reset_rows = set() if resets is None else {int(r) for r in np.asarray(resets).ravel()}
    out = np.empty(S.shape[0], dtype=np.int64)
    for j in range(S.shape[0]):
        if j in reset_rows:
            decoder.reset()
        out[j] = decoder.update(S[j])
    return out


def zscore_rows(scores: Any) -> np.ndarray:
    """Each row minus its mean, divided by its standard deviation (1 where constant).

    Makes one temperature comparable across methods whose scores live on different scales.

    Returns
    -------
    ndarray of the same shape, float64
    """
    S = np.asarray(scores, dtype=np.float64)
    if S.ndim != 2:
        raise InvalidParameterError(f"scores must be 2-D (n_queries, N); got shape {S.shape}.")
    return _zscore_in_place(S.copy())


def _zscore_in_place(S: np.ndarray) -> np.ndarray:
    """:func:`zscore_rows` of a float64 (n, N) array that may be overwritten (no second (n, N) array)."""
    std = S.std(axis=1, keepdims=True)
    S -= S.mean(axis=1, keepdims=True)
    S /= np.where(std > 0, std, 1.0)
    return S


def emission_scores(model: Any, Q: Any) -> np.ndarray:
    """HMM emissions of any fitted method: its ``place_scores(Q)`` z-scored per query row.

    Returns
    -------
    ndarray of shape (n_queries, N), float64
    """
    return zscore_rows(model.place_scores(Q))


def predict_sequence(model: Any, Q: Any, decoder: str = "hmm", **options: Any) -> np.ndarray:
    """:meth:`btel.methods.base.PlaceLocalizer.predict_sequence` of a fitted ``model`` (its docstring)."""
    if decoder == "median":
        from .filter import filter_sequence

        unknown = set(options) - {"window"}
        if unknown:
            raise InvalidParameterError(f"decoder='median' takes only window; got {sorted(unknown)}.")
        return model._check_answers(
            filter_sequence(model.predict(Q), options.get("window", 5), n_places=int(model.n_places_)))
    if decoder == "hmm":
        unknown = set(options) - set(HMM_OPTIONS)
        if unknown:
            raise InvalidParameterError(
                f"decoder='hmm' takes {', '.join(HMM_OPTIONS)}; got {', '.join(sorted(unknown))}.")
        check_is_fitted(model, model._fitted_marker)
        decoder_ = HMMDecoder(int(model.n_places_), **options)
        Qt = model._check_queries(Q)
        out = np.empty(Qt.shape[0], dtype=np.int64)
        for start, _, block in model._score_blocks(Qt):
            for j, scores in enumerate(_zscore_in_place(np.asarray(block, dtype=np.float64))):
                out[start + j] = decoder_.update(scores)
        return model._check_answers(out)
    raise InvalidParameterError(f"decoder must be 'hmm' or 'median'; got {decoder!r}.")
