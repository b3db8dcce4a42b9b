"""Storage accounting: the one storage rule, byte budgets, and their units.

The storage rule (docs/guide/concepts.md), for every method in btel: **a model's storage is the sum of
``ndarray.nbytes`` over the arrays that inference reads, at their stored dtype.** A model file
(:mod:`btel.core.modelfile`) holds exactly those arrays plus a small JSON header, so ``file size −
reported bytes`` is only the container overhead (a few hundred bytes per array; checked ≤ 4 KiB in
the tests).

The same rule, stated once for every method: **anything regenerated from a recorded seed costs 0
bytes** (btel-codes' codewords, regenerated from (family, N, K, seed); lsh's d×P Gaussian
projection, regenerated from its seed), **and anything learned is counted at its stored width**
(weights, codebooks, rotations, codes, and every front-end array: PCA whitening at float32,
shrinkage whitening's float16 mean and 4-bit basis). Runtime caches built from stored arrays
(dequantised weights, unpacked codes, faiss indexes) are memory, not storage.
"""

from __future__ import annotations

import re
from typing import Any, Mapping

import numpy as np

from ..exceptions import BudgetExceededError, InvalidParameterError

__all__ = ["check_within_budget", "parse_budget", "budget_of", "format_bytes", "exact_bytes", "storage_breakdown"]

_UNITS = {
    "": 1,
    "B": 1,
    "KB": 1000,
    "MB": 1000**2,
    "GB": 1000**3,
    "KIB": 1024,
    "MIB": 1024**2,
    "GIB": 1024**3,
}


def parse_budget(budget: int | float | str | None) -> int | None:
    """Turn a byte budget into an integer number of bytes.

    Decimal units as in the paper (``KB`` = 1000 B, ``MB`` = 10^6 B); binary units are
    spelled ``KiB``/``MiB``. Case-insensitive, spaces allowed: ``"500KB"``, ``"2 MB"``,
    ``"64KiB"``, ``"500kb"``, ``1_000_000`` — except ``Kb``/``Mb``/``Gb`` (a capital prefix and a
    small b), the usual spelling of bits, which is refused. A budget must be at least one byte; a
    fraction of a byte is rounded down (``"1.5B"`` is 1 B, ``"0.5KB"`` 500 B).

    Returns
    -------
    int or None
        Bytes, or None when ``budget`` is None (no budget).
    """
    if budget is None:
        return None
    if isinstance(budget, bool):
        raise InvalidParameterError(f"budget must be a number of bytes or a string like '500KB'; got {budget!r}.")
    if isinstance(budget, (int, np.integer)):  # exact: through float, 10**400 overflowed and 2**63 + 5 was rounded
        value = int(budget)
    elif isinstance(budget, (float, np.floating)):
        value = float(budget)
    elif isinstance(budget, str):
        match = re.fullmatch(r"\s*([+-]?[0-9]*\.?[0-9]+(?:[eE][+-]?[0-9]+)?)\s*([A-Za-z]*)\s*", budget)
        unit = match.group(2).upper() if match else None
        if match is not None and re.fullmatch(r"[KMG]i?b", match.group(2)):
            # Kb, Mb, Gb are the usual spelling of kilo-, mega- and gigabits: refused rather than read
            # as bytes, 8 times the meant size.
            raise InvalidParameterError(
                f"budget {budget!r}: '{match.group(2)}' reads as bits, and budgets are bytes; write "
                f"'{match.group(1)}{match.group(2)[:-1]}B' for bytes."
            )
        if match is None or unit not in _UNITS:
            raise InvalidParameterError(
                f"budget {budget!r} is not understood; write bytes or a size such as '500KB', "
                "'2MB' or '64KiB' (KB = 1000 B, KiB = 1024 B)."
            )
        value = float(match.group(1)) * _UNITS[unit]
    else:
        raise InvalidParameterError(f"budget must be a number of bytes or a string like '500KB'; got {budget!r}.")
    if not value > 0:  # NaN included
        raise InvalidParameterError(f"budget must be a positive number of bytes; got {budget!r}.")
    if value < 1:  # stored bytes are whole: it would be read as 0 B
        raise InvalidParameterError(f"budget {budget!r} is less than one byte; give a whole number of bytes or a "
                                    "size such as '500KB'.")
    if value > UNLIMITED_BUDGET:  # a model file records its budget: every budget reads back as written
        text = str(budget)
        shown = text if len(text) <= 24 else f"of {len(text)} digits" if isinstance(value, int) else text[:24] + "…"
        raise InvalidParameterError(f"budget {shown} is more bytes than any model stores (at most 2^62 B, 4.6 EB); "
                                    "leave the budget out (None; on the command line, no --budget) for none.")
    return int(value)


#: What a method's ``budget`` parameter is, in one sentence (``btel methods --params``).
#: A budget no model reaches: a planner run with it gives the largest model its parameters allow
#: (``budget_saturated()`` compares a fitted model's configuration with that one).
UNLIMITED_BUDGET = 1 << 62

BUDGET_MEANING = "Byte budget of everything stored (500000, '500KB', '2MB', '64KiB'); None: unbudgeted."


def budget_of(estimator: Any) -> int | None:
    """The byte budget of ``estimator`` (its ``budget`` parameter, declared on
    :class:`btel.methods.base.PlaceLocalizer`), parsed: bytes, or None when it has none."""
    return parse_budget(getattr(estimator, "budget", None))


def exact_bytes(n_bytes: int) -> str:
    """A size for a message: ``'492.2 KB (492240 B)'``, or ``'100 B'`` when the rounded form is exact."""
    rounded = format_bytes(n_bytes)
    return rounded if rounded == f"{int(n_bytes)} B" else f"{rounded} ({int(n_bytes)} B)"


def format_bytes(n_bytes: float) -> str:
    """Human-readable decimal size: ``format_bytes(492240) == '492.2 KB'``."""
    for unit, size in (("GB", 1e9), ("MB", 1e6), ("KB", 1e3)):
        if n_bytes >= size:
            return f"{n_bytes / size:.1f} {unit}"
    return f"{int(n_bytes)} B"


def storage_breakdown(arrays: Mapping[str, np.ndarray]) -> dict[str, int]:
    """Bytes per stored array: the one storage rule every method uses.

    Parameters
    ----------
    arrays : mapping of str to ndarray
        The arrays inference reads, at their stored dtype.

    Returns
    -------
    dict of str to int
        ``{name: array.nbytes}``; the model's storage is the sum of the values.
    """
    return {name: int(np.asarray(a).nbytes) for name, a in arrays.items()}




def check_within_budget(label: str, nbytes: int | None, budget: int | None) -> None:
    """Fail the run when a method stored more than its budget: a bug in its budget fitting."""
    if budget is not None and nbytes is not None and nbytes > budget:
        raise BudgetExceededError(
            f"{label} stores {nbytes} B, over its budget of {budget} B: a bug in its budget fitting."
        )


def spent_text(model: Any) -> str:
    """``"6,496 B of the 8,000 B budget"`` (or ``"… B (no budget)"``): a fitted model's bytes against its budget."""
    budget = budget_of(model)
    return f"{model.nbytes:,d} B of the {budget:,d} B budget" if budget is not None else f"{model.nbytes:,d} B (no budget)"


def summary_line(model: Any) -> str:
    """A fitted model's default ``summary()``: its method, N and d, its bytes against its budget, its front end."""
    return (f"{model.label}: N = {model.n_places_} places, d = {model.n_features_in_}; {spent_text(model)}; "
            f"front end {model.front_end_.describe()}")

