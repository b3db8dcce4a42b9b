"""The map-only rule of ``auto``: method and front end from the map and the budget alone.

No query is read. With P = 8 · budget / N the bits per map row the budget holds and d the
descriptor width, the rule reads the map's index order (:mod:`~btel.methods.auto.statistics`):

1. **Route** (route share ≥ 0.5 and route continuity ≥ 0.75) → ``btel-codes``, periodic codes.
2. **Ordered map** (continuity ≥ 0.6) where LSH's codes would carry fewer than
   :data:`ORDER_BITS_FACTOR` × 2·log2 N effective bits per row (the birthday bound) → the same codes;
   on maps of more than :data:`CODES_PLACES_PER_DIMENSION` places per dimension only below the bound
   itself (a linear classifier on d features cannot learn the short-period columns of so many places).
3. **The exact search fits** (no budget, or N·d float32 values within it) → brute force.
4. **Otherwise** → ``lsh`` (asymmetric scoring, the budget filled up to 16·d bits per row).

The front end of steps 3–4: **whitened** (``whiten='shrink'``) on independent places (continuity
< 0.6) when P ≥ d — with bits to spare the metric, not the sketch, limits, and whitening sharpens
the exact-place match, which is all independent places ask; along an ordered map it flattens the
slow variation that a tolerance of a few places relies on, so there it is never chosen from the map.
**Centred** (``lsh`` ``center=True``) when P < d, the rows lie in a cone (cone ratio ≥ 0.5) and
the mean (d float16 values) takes at most an eighth of the budget: uncentred sign bits then carry
far less than a bit each. **Plain cosine** otherwise. Whether a
transform carries over from the map's condition to the queries' cannot be read from the map: with
labelled queries, calibrate (:mod:`btel.methods.auto.calibrate`) — every front-end variant is among
the calibrated candidates.

Thresholds: the three of the index order, :data:`ORDER_BITS_FACTOR` and
:data:`CODES_PLACES_PER_DIMENSION`, P against d and the cone ratio; PQ, OPQ and RaBitQ are calibrated candidates, not map-only ones. The mechanisms, the maps
made to test them and the figures: ``docs/decisions/auto-rule.md``.

A choice that does not fit the budget falls back to the next candidate (plain ``lsh``, then
``btel-codes``); what was chosen and why is recorded in ``choice_``.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ...core.storage import format_bytes
from .statistics import CONTINUITY_GAPS, ROUTE_WINDOW, collision_bits, index_order, map_cone_ratio

__all__ = ["CODES_PLACES_PER_DIMENSION", "ORDER_BITS_FACTOR", "choose_method", "front_end_variant"]

#: An ordered map gets output codes while LSH's effective bits per row are below this × 2·log2 N.
ORDER_BITS_FACTOR = 2.0
#: Beyond this many map places per descriptor dimension an ordered map gets the codes only below the bound itself.
CODES_PLACES_PER_DIMENSION = 32


def front_end_variant(n_rows: int, d: int, budget: int | None, cone: float, kind: str) -> tuple[str, str]:
    """``('shrink' | 'centre' | 'plain', why)``: the front end of steps 3–4 (module docstring); ``kind`` is
    :func:`~btel.methods.auto.statistics.index_order`'s."""
    from ..baselines.lsh import CENTER_CONE

    bits = None if budget is None else 8 * budget / n_rows
    if kind == "independent" and (bits is None or bits >= d):
        room = "no budget" if bits is None else f"P = {bits:.0f} ≥ d = {d}"
        return "shrink", f"independent places, {room}: shrinkage-whitened rows"
    if bits is not None and bits < d and cone >= CENTER_CONE and 2 * d <= budget / 8:
        return "centre", f"P = {bits:.0f} < d = {d}, cone ratio {cone:.2f} ≥ {CENTER_CONE}: centred rows"
    room = "no budget" if bits is None else f"P = {bits:.0f} {'≥' if bits >= d else '<'} d = {d}"
    return "plain", f"{room}, cone ratio {cone:.2f}: plain cosine rows"


def _variant_params(method: str, variant: str, whiten: Any) -> dict[str, Any]:
    params: dict[str, Any] = {"whiten": "shrink"} if variant == "shrink" else {}
    if method == "lsh":
        params["center"] = variant == "centre"
    if whiten is not None:  # the user's front end wins
        params["whiten"] = whiten
    return params


def choose_method(X: np.ndarray, places: np.ndarray | None, n_places: int, budget: int | None,
                  whiten: Any = None) -> list[dict[str, Any]]:
    """The candidates, best first, that the rule gives for this map and budget (module docstring).

    Parameters
    ----------
    X : ndarray of shape (n_rows, n_features)
    places : ndarray of shape (n_rows,), int, or None
    n_places : int
    budget : int or None
    whiten : None or the user's ``whiten``
        None: the rule chooses; anything else is given to every candidate.

    Returns
    -------
    list of dict
        ``{"method", "params", "reason", ...statistics}``; :class:`AutoLocalizer` fits the first
        that fits the budget.
    """
    from ..baselines.lsh import LSHLocalizer

    order = index_order(X, places)
    n_rows, d = X.shape
    cone = map_cone_ratio(X)
    bits = None if budget is None else 8 * budget / n_rows
    stats = {"route_share": round(order.share, 4), "route_continuity": round(order.continuity, 4),
             "cone_ratio": round(cone, 4), "bits_per_row": None if bits is None else round(bits, 1),
             "bytes_per_place": None if budget is None else round(budget / n_rows, 2),
             "n_places": int(n_places), "n_rows": int(n_rows), "n_features": int(d)}
    variant, front_why = front_end_variant(n_rows, d, budget, cone, order.kind)
    plain = {} if whiten is None else {"whiten": whiten}
    lsh_plain = {"method": "lsh", "params": {**plain, "center": False}, "reason": "fallback: plain LSH"}
    codes = {"method": "btel-codes", "params": {**plain, "code": "periodic"},
             "reason": "fallback: periodic output codes filling the budget"}
    out: list[dict[str, Any]] = []
    if order.kind == "route":
        out.append({**codes, "reason": f"route ({order.why}): periodic output codes filling the budget"})
    elif order.kind == "ordered" and budget is not None:
        centred = variant == "centre"
        effective = LSHLocalizer(center=centred).effective_bits(n_rows, d, budget, cone)
        stats["lsh_effective_bits"] = round(effective, 1)
        # The codes' classifiers cannot resolve them all; they see the user's whitening rank, if one is given.
        seen = int(whiten) if isinstance(whiten, (int, np.integer)) and not isinstance(whiten, bool) else d
        many = n_places > CODES_PLACES_PER_DIMENSION * seen
        factor = 1.0 if many else ORDER_BITS_FACTOR
        few = factor * collision_bits(n_rows)
        if effective < few:
            how = "centred" if centred else "uncentred"
            crowd = (f" (N = {n_places} places > {CODES_PLACES_PER_DIMENSION}·d: the bound itself)" if many
                     else "")
            why = (f"ordered map ({order.why}); LSH would carry ≈ {effective:.1f} effective bits per row "
                   f"(P = {bits:.0f}, cone ratio {cone:.2f}, {how}) < {factor:g} × 2·log2 N = "
                   f"{few:.1f}{crowd}: periodic output codes filling the budget")
            out.append({**codes, "reason": why})
    if not out:
        kind = {"route": "route", "ordered": "ordered map", "independent": "independent places"}[order.kind]
        where = f"{kind} ({order.why})"
        if budget is None or n_rows * d * 4 <= budget:
            room = "no budget" if budget is None else f"N·d float32 = {format_bytes(n_rows * d * 4)} fits"
            out.append({"method": "bruteforce", "params": _variant_params("bruteforce", variant, whiten),
                        "reason": f"{where}; {room}: exact search; {front_why}"})
        out.append({"method": "lsh", "params": _variant_params("lsh", variant, whiten),
                    "reason": f"{where}; asymmetric LSH; {front_why}"})
    out += [c for c in (lsh_plain, codes) if all(c["method"] != o["method"] or c["params"] != o["params"]
                                                  for o in out)]
    return [{**c, **stats} for c in out]


#: What each figure in a reason means, for a reader who has not read the rule (auto's ``summary()``).
_TERMS = (
    ("route share", f"route share = share of map rows whose most similar row of another place lies within "
                    f"{ROUTE_WINDOW} places"),
    ("continuity", f"continuity = how much more alike rows {CONTINUITY_GAPS[0]}–{CONTINUITY_GAPS[1]} places apart "
                   "are than other rows (0.5: the order says nothing, 1: a smooth route)"),
    ("P = ", "P = bits per map row the budget holds (8 · budget / N)"),
    ("d = ", "d = descriptor width"),
    ("cone ratio", "cone ratio = length of the mean unit row (near 1: the rows point one way)"),
    ("effective bits", "effective bits = what LSH's P sign bits are worth on these rows"),
    ("the bound itself", f"N > {CODES_PLACES_PER_DIMENSION}·d = more places than the codes' linear classifiers on d "
                         "features can tell apart finely"),
)


def reason_terms(reason: str) -> str:
    """One line defining the figures that ``reason`` (a candidate's ``"reason"``) uses; '' if none."""
    used = [text for word, text in _TERMS if word in reason]
    return "" if not used else "where " + "; ".join(used) + " (the rule: docs/decisions/auto-rule.md)."

