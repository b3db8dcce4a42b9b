"""Where BTEL loses the information: per-bit accuracy on the queries against tree level.

Bit level 1 is the MSB (it splits the route into two long halves), level b the LSB (it alternates
between neighbouring places). For each level, :func:`bit_accuracy` gives the share of queries
whose margin has the sign of their true place's bit, next to two references:

- the *majority rate*: the share of the commonest bit value among the queries (a classifier that
  always answers it scores this — for N not a power of two the top bits are unbalanced, and on a
  short stretch of the route a high bit may be constant);
- the *balanced accuracy*: the mean of the accuracies on true-0 and true-1 queries (0.5 means no
  information whatever the balance; NaN where only one value occurs);
- the *mutual information* between the true and the predicted bit (bits, from the empirical 2×2
  table). Summed over the levels it bounds what one frame tells about its place: a tolerance of t
  needs about log2(N / (2t + 1)) bits (7.4 at N = 3576, t = 10).

:func:`localizer_bit_accuracy` measures a fitted BTEL model (each query on its *true* region's
tree, so that region errors do not mix in; the region accuracy is reported on its own), or a
 ``block_size > 1`` (bits of the true block). :func:`plot_bit_accuracy`
draws the curves (matplotlib Agg, like :mod:`btel.evaluation.plots`).
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from ...core.validation import check_descriptors, check_is_fitted
from .encoding import encode, n_bits_for
from ...exceptions import InvalidParameterError

__all__ = ["BitDiagnostics", "bit_accuracy", "localizer_bit_accuracy", "plot_bit_accuracy"]


@dataclass
class BitDiagnostics:
    """Per-level accuracy of the bit classifiers on a set of queries.

    Attributes
    ----------
    accuracy : ndarray of shape (b,), float64
        Share of queries whose margin sign equals the true bit (NaN where no query has that level).
    balanced : ndarray of shape (b,), float64
        Mean of the accuracies on true-0 and true-1 queries (NaN where one value is missing).
    majority : ndarray of shape (b,), float64
        Share of the commonest true bit value.
    counts : ndarray of shape (b,), int64
        Queries measured at each level.
    mutual_information : ndarray of shape (b,), float64
        I(true bit; predicted bit) in bits (0 where no query has that level).
    region_accuracy : float or None
        Share of queries whose predicted region is their true region (None when r = 1).
    """

    accuracy: np.ndarray
    balanced: np.ndarray
    majority: np.ndarray
    counts: np.ndarray
    mutual_information: np.ndarray | None = None
    region_accuracy: float | None = None

    @property
    def levels(self) -> np.ndarray:
        """Bit levels 1 … b (1 = MSB)."""
        return np.arange(1, self.accuracy.size + 1)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready (NaN → None)."""
        def clean(a: np.ndarray) -> list[float | None]:
            return [None if not np.isfinite(v) else float(v) for v in np.asarray(a, dtype=np.float64)]

        return {"levels": self.levels.tolist(), "accuracy": clean(self.accuracy), "balanced": clean(self.balanced),
                "majority": clean(self.majority), "counts": self.counts.astype(int).tolist(),
                "mutual_information": None if self.mutual_information is None else clean(self.mutual_information),
                "information_per_query": None if self.mutual_information is None
                else float(np.nansum(self.mutual_information)),
                "region_accuracy": self.region_accuracy}


def bit_accuracy(margins: Any, true_bits: Any) -> BitDiagnostics:
    """Per-level accuracy of bit margins against the true bits.

    Parameters
    ----------
    margins : array-like of shape (n_queries, b)
        Positive = bit 1; NaN entries (a level the query's tree does not have) are skipped.
    true_bits : array-like of shape (n_queries, b), values in {0, 1}
        MSB first (:func:`btel.methods.btel.encoding.encode` of the true places).

    Returns
    -------
    BitDiagnostics
    """
    m = np.asarray(margins, dtype=np.float64)
    t = np.asarray(true_bits)
    if m.ndim != 2 or m.shape != t.shape:
        raise InvalidParameterError(f"margins {m.shape} and true_bits {t.shape} must be 2-D arrays of one shape.")
    valid = np.isfinite(m)
    predicted = m > 0
    truth = t.astype(bool)
    counts = valid.sum(axis=0)
    with np.errstate(invalid="ignore", divide="ignore"):
        correct = ((predicted == truth) & valid).sum(axis=0)
        accuracy = np.where(counts > 0, correct / np.maximum(counts, 1), np.nan)
        ones = (truth & valid).sum(axis=0)
        zeros = counts - ones
        tpr = ((predicted & truth & valid).sum(axis=0)) / ones
        tnr = ((~predicted & ~truth & valid).sum(axis=0)) / zeros
        balanced = np.where((ones > 0) & (zeros > 0), (tpr + tnr) / 2, np.nan)
        majority = np.where(counts > 0, np.maximum(ones, zeros) / np.maximum(counts, 1), np.nan)
    # Empirical joint of (true, predicted) per level → mutual information in bits.
    joint = np.stack([((truth == tv) & (predicted == pv) & valid).sum(axis=0)
                      for tv in (False, True) for pv in (False, True)]).astype(np.float64)  # (4, b)
    with np.errstate(invalid="ignore", divide="ignore"):
        pj = joint / np.maximum(counts, 1)
        pt = np.stack([pj[0] + pj[1], pj[0] + pj[1], pj[2] + pj[3], pj[2] + pj[3]])
        pp = np.stack([pj[0] + pj[2], pj[1] + pj[3], pj[0] + pj[2], pj[1] + pj[3]])
        terms = np.where(pj > 0, pj * np.log2(pj / (pt * pp)), 0.0)
    information = np.maximum(terms.sum(axis=0), 0.0)
    return BitDiagnostics(accuracy.astype(np.float64), balanced.astype(np.float64), majority.astype(np.float64),
                          counts.astype(np.int64), information)


def localizer_bit_accuracy(model: Any, Q: Any, true_places: Any) -> BitDiagnostics:
    """Per-level bit accuracy of a fitted compressed BTEL model on queries.

    Each query is read by its true region's tree (levels are that tree's own, MSB = 1; a tree with
    fewer bits leaves NaN at the deeper levels), so the figure isolates the bit classifiers; the
    region classifier's accuracy is :attr:`BitDiagnostics.region_accuracy`.

    Parameters
    ----------
    model : BTELocalizer
        Fitted, ``scheme='compressed'``. With ``block_size > 1`` the bits are the true block's;
        with ``code_copies > 1`` only the b plain bits are scored.
    Q : array-like of shape (n_queries, n_features)
    true_places : array-like of int, shape (n_queries,)
        True place of each query (frame-aligned: ``np.arange(n_queries)`` for the first rows).

    Returns
    -------
    BitDiagnostics
    """
    check_is_fitted(model, "n_places_")
    if getattr(model, "scheme", None) != "compressed":
        raise InvalidParameterError("per-bit accuracy needs one classifier per bit (scheme='compressed').")
    truth = np.asarray(true_places, dtype=np.int64)
    Qc = check_descriptors(Q, name="Q", n_features=model.n_features_in_)
    if truth.shape != (Qc.shape[0],) or truth.min(initial=0) < 0 or truth.max(initial=0) >= model.n_places_:
        raise InvalidParameterError(
            f"true_places must hold one place in [0, {model.n_places_}) per query row ({Qc.shape[0]})."
        )
    truth = truth // model.block_size_  # the trees index blocks
    starts, sizes, offsets = model.region_starts_, model.region_sizes_, model.tree_offsets_
    region = np.searchsorted(starts, truth, side="right") - 1
    all_margins = model.column_margins(Qc).astype(np.float64)
    b = n_bits_for(int(sizes.max())) if sizes.max() >= 2 else 1
    margins = np.full((Qc.shape[0], b), np.nan)
    bits = np.zeros((Qc.shape[0], b), dtype=np.uint8)
    for k in np.unique(region).tolist():
        rows = np.flatnonzero(region == k)
        n_k = int(sizes[k])
        if n_k < 2:
            continue
        b_k = n_bits_for(n_k)
        margins[rows, :b_k] = all_margins[rows, offsets[k] : offsets[k] + b_k]
        bits[rows, :b_k] = encode(truth[rows] - starts[k], b_k)
    out = bit_accuracy(margins, bits)
    if int(model.n_regions_) > 1:
        out.region_accuracy = float(np.mean(model.predict_region(Qc) == region))
    return out


def answer_bit_accuracy(predictions: Any, true_places: Any, n_places: int) -> BitDiagnostics:
    """Per-level accuracy of the bits of predicted places against the true places' bits.

    The bits are BTEL's code of ``n_bits_for(n_places)`` bits; any method's answers can be scored
    (the unbudgeted nearest neighbour's place says what the descriptor itself carries across a
    condition change).

    Parameters
    ----------
    predictions, true_places : array-like of int, shape (n_queries,)
    n_places : int
        Map places N.

    Returns
    -------
    BitDiagnostics
    """
    b = n_bits_for(int(n_places))
    return bit_accuracy(2.0 * encode(np.asarray(predictions), b) - 1.0, encode(np.asarray(true_places), b))


def plot_bit_accuracy(
    curves: Mapping[str, BitDiagnostics],
    path: str | os.PathLike,
    *,
    title: str | None = None,
    balanced: bool = False,
) -> Figure:
    """Per-bit accuracy against bit level (1 = MSB), one line per variant, saved as PNG.

    The majority rate of the first curve is drawn dotted (0.5 is the chance line for balanced
    accuracy).

    Parameters
    ----------
    curves : mapping of str to BitDiagnostics
        Label → diagnostics (e.g. ``"BTE-C HOG"``, ``"BTE-C patchnorm"``, ``"tolerant B=8"``).
    path : path
        PNG file to write.
    title : str, optional
    balanced : bool
        Plot balanced accuracy instead of accuracy.

    Returns
    -------
    matplotlib.figure.Figure
    """
    if not curves:
        raise InvalidParameterError("plot_bit_accuracy needs at least one curve.")
    fig = Figure(figsize=(6.4, 4.4), dpi=120)
    FigureCanvasAgg(fig)
    ax = fig.add_subplot(1, 1, 1)
    for label, diag in curves.items():
        values = diag.balanced if balanced else diag.accuracy
        ax.plot(diag.levels, values, marker="o", label=label)
    first = next(iter(curves.values()))
    if balanced:
        ax.axhline(0.5, color="grey", linestyle=":", label="chance")
    else:
        ax.plot(first.levels, first.majority, color="grey", linestyle=":", label="majority rate (first curve)")
    ax.set_xlabel("bit level (1 = MSB, long stretches; b = LSB, neighbours)")
    ax.set_ylabel("balanced accuracy on queries" if balanced else "bit accuracy on queries")
    ax.set_ylim(0.3, 1.0)
    if title:
        ax.set_title(title)
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.tight_layout()
    fig.savefig(path, format="png")
    return fig
