"""Storage layout and budget planner of the output-code localizer (:mod:`btel.methods.codes.estimator`).

Stored arrays (the storage rule counts each at its stored width):

- ``weights`` — K × d' at 32 / 16 / 8 / 4 bits (:mod:`btel.methods.codes.quantise`), ``scales`` — K float32 below 32 bits;
- ``bias`` — K float32;
- ``columns`` — the d' kept descriptor columns, uint16 (uint32 beyond 65 536), shared by every
  code column; absent when d' = d.

The codewords cost 0 bytes (regenerated from the family, N, K and seed in the header).

**The planner fills the budget** (``plan_codes``). Given the bytes left after the front end, the
descriptor dimension d after the front end, and whatever the user fixed (K, d', bits):

1. Weight width: 4 bits, unless given. At 4 bits the decoders lost nothing measurable against
   32 bits (``btel experiment codes``), so 4 bits buys 8× more weights for the same bytes.
2. K and d' grow together, K = d', until d' reaches d ("square rule"); the bytes left over at the
   largest fitting square go to more code columns K (never more kept columns). Once d' = d, all
   further bytes go to K. On Gardens Point and synthetic routes (``btel experiment codes``), at
   a fixed budget, K ≈ d' was the best split or within noise of it; both a tall (K ≫ d') and a
   wide (d' ≫ K) split lost — more columns per code cannot make up for too few codes to tell N
   places apart, and many codes on few columns all see the same projection.
3. K stays within the family's range: at least b = ⌈log2 N⌉, at most :data:`MAX_AUTO_CODES`
   (binary: exactly b; offset: its number of distinct columns). When K is at its maximum and
   d' = d, the width is raised (8, 16, 32 bits) while it fits — the only bytes left to spend.
4. Kept columns (d' < d) are the d' columns of largest variance on the map (unsupervised, shared
   by every code; ties to the lower index). Per-code selection as BTE-C does would store K × d'
   indices — at 4 bits, 2-byte indices would cost 4× the weights they index.

Never over budget: each step takes the largest value whose planned bytes fit, and the fitted
model's arrays match :func:`code_array_specs` exactly. When even K = b codes on one column does
not fit, :class:`~btel.exceptions.BudgetTooSmallError` names the minimum. Without a budget:
K = 256 (within the family's range), d' = d, 4 bits.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..base import ArraySpec
from .codebook import max_columns, min_columns
from ...exceptions import BudgetTooSmallError
from ...learning.feature_selection import column_index_dtype
from .quantise import WEIGHT_BITS, weight_specs
from ...core.storage import format_bytes

__all__ = ["CodePlan", "code_array_specs", "code_planned_bytes", "plan_codes", "MAX_AUTO_CODES",
           "DEFAULT_CODES", "DEFAULT_BITS"]

#: Most code columns the planner chooses by itself (decode cost is O(N·K) per query).
MAX_AUTO_CODES = 4096
#: K without a budget.
DEFAULT_CODES = 256
#: Weight width the planner starts from.
DEFAULT_BITS = 4


def code_array_specs(n_codes: int, n_selected: int, n_features: int, bits: int) -> dict[str, ArraySpec]:
    """Shape and dtype of every array a code localizer of this shape stores (front end excluded)."""
    specs = dict(weight_specs(n_codes, n_selected, bits))
    specs["bias"] = ArraySpec((n_codes,), np.float32)
    if n_selected < n_features:
        specs["columns"] = ArraySpec((n_selected,), column_index_dtype(n_features))
    return specs


def code_planned_bytes(n_codes: int, n_selected: int, n_features: int, bits: int) -> int:
    """Bytes of :func:`code_array_specs`."""
    return int(sum(s.nbytes for s in code_array_specs(n_codes, n_selected, n_features, bits).values()))


@dataclass(frozen=True)
class CodePlan:
    """What the planner chose: K codes × d' kept columns at ``bits``, and why."""

    n_codes: int
    n_selected: int
    bits: int
    nbytes: int
    budget: int | None
    rule: str

    def describe(self) -> str:
        room = "" if self.budget is None else f" of {self.budget:,d} B available"
        return (f"K = {self.n_codes} codes × d' = {self.n_selected} columns at {self.bits} bits: "
                f"{self.nbytes:,d} B{room} ({self.rule})")


def _largest(low: int, high: int, fits) -> int:
    """Largest v in [low, high] with fits(v) (fits is monotone: true up to some v); low − 1 if none."""
    if high < low or not fits(low):
        return low - 1
    while low < high:
        mid = (low + high + 1) // 2
        if fits(mid):
            low = mid
        else:
            high = mid - 1
    return low


def plan_codes(available: int | None, n_features: int, n_places: int, family: str, *,
               n_codes: int | None = None, n_selected: int | None = None, bits: int | None = None) -> CodePlan:
    """Choose K, d' and the weight width for a budget (module docstring for the rule).

    Parameters
    ----------
    available : int or None
        Bytes left for the codes (budget minus the front end); None: no budget.
    n_features : int
        d after the front end.
    n_places : int
        N.
    family : str
        Code family (bounds K).
    n_codes, n_selected, bits : int, optional
        Fixed by the user (the planner chooses the others).

    Raises
    ------
    BudgetTooSmallError
        Nothing fits.
    """
    d = int(n_features)
    k_lo, k_hi = min_columns(family, n_places), min(max_columns(family, n_places), MAX_AUTO_CODES)
    if family == "binary":
        k_hi = k_lo
    if n_codes is not None:
        k_lo = k_hi = int(n_codes)
    d_hi = d if n_selected is None else min(int(n_selected), d)
    d_lo = d_hi if n_selected is not None else 1
    widths = [int(bits)] if bits is not None else [DEFAULT_BITS]

    def size(k: int, s: int, w: int) -> int:
        return code_planned_bytes(k, s, d, w)

    if available is None:
        k = min(max(DEFAULT_CODES, k_lo), k_hi) if n_codes is None else k_lo
        return CodePlan(k, d_hi, widths[0], size(k, d_hi, widths[0]), None,
                        "no budget: K = 256 within the family's range, every column, 4 bits")
    w = widths[0]
    minimum = size(k_lo, d_lo, w)
    if minimum > available:
        raise BudgetTooSmallError(
            f"{format_bytes(available)} ({available} B) is too small for output codes of the {family} family on "
            f"N = {n_places} places: the smallest model (K = {k_lo} codes × d' = {d_lo} column at {w} bits) needs "
            f"{minimum} B. Raise the budget, or fix fewer codes (n_codes).", budget=available, minimum=minimum)
    if n_selected is None and n_codes is None:
        # Square rule: the largest s with K = clip(s) and d' = s that fits, then the rest to K.
        # (s = 1 with K = b fits: the minimum was checked above.)
        s = _largest(d_lo, d_hi, lambda v: size(min(max(v, k_lo), k_hi), v, w) <= available)
        k = _largest(min(max(s, k_lo), k_hi), k_hi, lambda v: size(v, s, w) <= available)
        rule = "d' = d, every byte left to K" if s == d else "square rule: K = d' until d' = d, the rest to K"
    elif n_codes is None:  # d' fixed: the rest to K
        s = d_hi
        k = _largest(k_lo, k_hi, lambda v: size(v, s, w) <= available)
        rule = "d' fixed, the rest to K"
    else:  # K fixed: the rest to d'
        k = k_lo
        s = _largest(d_lo, d_hi, lambda v: size(k, v, w) <= available)
        rule = "K fixed, the rest to d'"
    if bits is None and k == k_hi and s == d_hi:
        wider = [b for b in WEIGHT_BITS if b > w and size(k, s, b) <= available]
        if wider:
            w = max(wider)
            rule += f"; K and d' at their maximum, weights widened to {w} bits"
    return CodePlan(int(k), int(s), int(w), size(k, s, w), int(available), rule)
