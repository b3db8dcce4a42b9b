"""Input checks shared by every estimator. Never ``assert``: these must survive ``python -O``."""

from __future__ import annotations

import numbers
from typing import Any

import numpy as np

from ..exceptions import (
    DimensionMismatchError,
    InvalidDescriptorsError,
    InvalidParameterError,
    ModelFileError,
    NotEnoughPlacesError,
)


def check_descriptors(
    X: Any,
    *,
    name: str = "X",
    n_features: int | None = None,
    min_rows: int = 1,
    dtype: type = np.float32,
    check_finite: bool = True,
    distinct_rows: bool = False,
) -> np.ndarray:
    """Validate a descriptor matrix and return it as a C-contiguous 2-D float array.

    Parameters
    ----------
    X : array-like of shape (n_samples, n_features)
        Descriptors, one row per image.
    name : str
        What to call the array in error messages.
    n_features : int, optional
        The dimension the array must have (the one the model was fitted on).
    min_rows : int
        Fewest rows accepted.
    dtype : numpy dtype
        Result dtype (float32 unless the caller needs float64).
    check_finite : bool
        False leaves the NaN/inf check to the caller, who must then do it in a pass it makes
        anyway (queries through a normalising front end: :func:`btel.core.frontend.normalize_rows`).
    distinct_rows : bool
        True (a map being fitted): refuse an array whose rows are all the same descriptor.

    Returns
    -------
    X : ndarray of shape (n_samples, n_features), dtype ``dtype``

    Raises
    ------
    InvalidDescriptorsError
        Not numeric, not 2-D, empty, with NaN/inf values, with finite values past ``dtype``'s range,
        or (``distinct_rows``) with every row the same.
    DimensionMismatchError
        ``n_features`` is given and differs from ``X.shape[1]``.
    """
    if (type(X) is np.ndarray or type(X) is np.memmap) and X.dtype == dtype and X.ndim == 2 and X.flags.c_contiguous:
        # Fast path: nothing to convert (shape and finiteness are still checked); a memory-mapped map stays
        # mapped, another subclass (np.matrix: its `*` and rows mean other things) becomes an ndarray.
        arr, fast = X, True
    else:
        arr, fast = _as_numeric_array(X, name), False
    if arr.ndim != 2:
        hint = " Use X.reshape(1, -1) for a single descriptor." if arr.ndim == 1 else ""
        raise InvalidDescriptorsError(
            f"{name} must be 2-D (n_samples, n_features); got shape {arr.shape}.{hint}"
        )
    if arr.shape[0] < max(1, min_rows) or arr.shape[1] == 0:
        raise InvalidDescriptorsError(
            f"{name} has shape {arr.shape}; it needs at least {max(1, min_rows)} row(s) and one column."
        )
    if n_features is not None and arr.shape[1] != n_features:
        raise DimensionMismatchError(
            f"{name} has {arr.shape[1]} features but the model was fitted on {n_features}. "
            "Use descriptors from the same extractor (and settings) as the map."
        )
    # No copy when X already has the right dtype and layout (memory-mapped maps stay mapped).
    if not fast:
        source, target = arr, np.dtype(dtype)
        narrowed = source.dtype.kind == "f" and target.kind == "f" and source.dtype.itemsize > target.itemsize
        with np.errstate(over="ignore"):  # a finite value past the narrower type's range is named below, not warned of
            arr = np.ascontiguousarray(arr, dtype=dtype)
        if narrowed:
            _raise_if_narrowing_lost(source, arr, name)
    if check_finite:
        raise_if_non_finite(arr, name)
    if distinct_rows:
        raise_if_rows_identical(arr, name)
    return arr


def _raise_if_narrowing_lost(source: np.ndarray, arr: np.ndarray, name: str) -> None:
    """Name what casting ``source`` to the narrower float ``arr`` lost: a finite value past its range, or all."""
    bad = _first_non_finite(arr)
    if bad is not None and np.isfinite(source[bad]):
        raise InvalidDescriptorsError(
            f"{name} row {bad[0]}, column {bad[1]} is {float(source[bad]):.3g}, outside {arr.dtype.name}'s "
            f"range (|v| ≤ {float(np.finfo(arr.dtype).max):.3g}); scale the descriptors down.")
    if bad is None and not arr.any() and source.any():
        raise InvalidDescriptorsError(
            f"every value of {name} is zero in {arr.dtype.name}: all are below its smallest number (largest |v| "
            f"{float(np.abs(source).max()):.3g}); scale the descriptors up.")


def raise_if_rows_identical(arr: np.ndarray, name: str) -> None:
    """Raise :class:`InvalidDescriptorsError` when every row of a map of ≥ 2 rows is the same descriptor.

    No place could be told from another. Read row block by row block, stopping at the first row that
    differs (on a real map: the second).
    """
    if arr.shape[0] < 2 or not np.array_equal(arr[1], arr[0]):
        return
    rows = max(1, (1 << 20) // max(arr.shape[1], 1))  # a 1 MB mask at a time
    for start in range(2, arr.shape[0], rows):
        if not (arr[start : start + rows] == arr[0]).all():
            return
    raise InvalidDescriptorsError(
        f"all {arr.shape[0]} rows of {name} are the same descriptor, so no place can be told from another. "
        "Check the map's images (blank or flat frames give one descriptor) and that the rows are their descriptors "
        "(not a constant placeholder).")


def raise_if_non_finite(arr: np.ndarray, name: str, *, row_offset: int = 0) -> None:
    """Raise :class:`InvalidDescriptorsError` naming the first NaN/inf of ``arr`` (rows counted from ``row_offset``)."""
    bad = _first_non_finite(arr)
    if bad is not None:
        raise InvalidDescriptorsError(
            f"{name} contains NaN or infinite values (first at row {bad[0] + row_offset}, column {bad[1]}). "
            "Remove or repair those rows before fitting or predicting."
        )


def _as_numeric_array(X: Any, name: str) -> np.ndarray:
    """``np.asarray(X)`` with the errors of :func:`check_descriptors` for what is not real numbers."""
    if hasattr(X, "toarray") and not isinstance(X, np.ndarray):
        raise InvalidDescriptorsError(f"{name} is a sparse matrix; btel needs dense descriptors. Convert it with "
                                      f"{name}.toarray().")
    if isinstance(X, np.ma.MaskedArray) and np.ma.getmaskarray(X).any():  # np.asarray would drop the mask unseen
        raise InvalidDescriptorsError(f"{name} has masked values; fill them ({name}.filled(...)) or drop those rows.")
    try:
        arr = np.asarray(X)
    except Exception as exc:  # ragged lists and the like
        raise InvalidDescriptorsError(f"{name} could not be read as a numeric array: {exc}") from exc
    if arr.dtype.kind not in "biufc":  # not object, text, dates or durations (numpy counts timedelta as a number)
        raise InvalidDescriptorsError(
            f"{name} has dtype {arr.dtype}; descriptors must be numbers (float32 preferred)."
        )
    if np.issubdtype(arr.dtype, np.complexfloating):
        raise InvalidDescriptorsError(f"{name} is complex; descriptors must be real numbers.")
    return arr


def _first_non_finite(arr: np.ndarray, chunk_elements: int = 1 << 22) -> tuple[int, int] | None:
    """(row, column) of the first NaN/inf in a 2-D float array, or None.

    Checked in row chunks of about ``chunk_elements`` values, so a 1 GB memory-mapped map needs a
    4 MB mask at a time instead of an N×d one.
    """
    if arr.size <= 1 << 16:
        # Small (one query, a few): the direct check has less fixed overhead than the screen.
        if np.isfinite(arr).all():
            return None
        row, col = np.argwhere(~np.isfinite(arr))[0]
        return int(row), int(col)
    rows = max(1, chunk_elements // max(arr.shape[1], 1))
    ones = np.ones(arr.shape[1], dtype=arr.dtype) if arr.dtype.kind == "f" else None
    for start in range(0, arr.shape[0], rows):
        block = arr[start : start + rows]
        # Screen with one BLAS pass (row sums): a NaN or inf anywhere in a row makes its sum
        # non-finite, so finite sums prove the block clean at a third of np.isfinite's cost
        # (no boolean mask). A non-finite sum may also be overflow of finite values, so only then
        # is the exact element check run.
        if ones is not None:
            with np.errstate(all="ignore"):
                if np.isfinite(block @ ones).all():
                    continue
        if not np.isfinite(block).all():
            row, col = np.argwhere(~np.isfinite(block))[0]
            return start + int(row), int(col)
    return None


def check_places(places: Any, n_samples: int) -> tuple[np.ndarray, int]:
    """Validate place labels: integers in ``[0, N)`` covering every place at least once.

    Returns
    -------
    places : ndarray of shape (n_samples,), dtype int64
    n_places : int
        N = ``places.max() + 1``.
    """
    arr = np.asarray(places)
    if arr.ndim != 1 or arr.shape[0] != n_samples:
        raise InvalidParameterError(
            f"places must be 1-D with one label per descriptor row ({n_samples}); got shape {arr.shape}."
        )
    if arr.dtype.kind == "f":
        if not np.all(np.isfinite(arr)) or not np.all(arr == np.round(arr)):
            raise InvalidParameterError("places must be whole numbers (place indices).")
    elif arr.dtype.kind not in "iu":
        raise InvalidParameterError(f"places must be integer place indices; got dtype {arr.dtype}.")
    if arr.dtype.kind == "f" and np.abs(arr).max() >= 2.0**62:
        raise InvalidParameterError("places must be place indices below the number of descriptor rows.")
    arr = arr.astype(np.int64)
    if arr.min() < 0:
        raise InvalidParameterError("places must be non-negative place indices.")
    n_places = int(arr.max()) + 1
    # The distinct labels, not a count table: a label of 10**12 must not ask for an 8 TB table.
    present = np.unique(arr)
    if present.size != n_places:
        gaps = np.flatnonzero(present != np.arange(present.size))
        first_missing = int(gaps[0]) if gaps.size else int(present.size)
        raise InvalidParameterError(
            f"places must cover every index 0..{n_places - 1}; {n_places - present.size} are missing "
            f"(first: {first_missing}). Renumber the places contiguously in route order."
        )
    if n_places < 2:
        raise NotEnoughPlacesError(
            f"N = {n_places} place(s): an index needs at least 2 places. Fit on a longer route."
        )
    return arr, n_places


def check_positive_int(value: Any, name: str, *, minimum: int = 1) -> int:
    """Return ``value`` as an int ≥ ``minimum`` or raise :class:`InvalidParameterError`."""
    if isinstance(value, bool) or not isinstance(value, numbers.Integral) or value < minimum:
        raise InvalidParameterError(f"{name} must be an integer ≥ {minimum}; got {value!r}.")
    return int(value)


def check_is_fitted(estimator: Any, attribute: str) -> None:
    """Raise :class:`NotFittedError` unless ``estimator`` has ``attribute``."""
    if not hasattr(estimator, attribute):
        from ..exceptions import NotFittedError  # built on first use: it imports scikit-learn

        raise NotFittedError(
            f"This {type(estimator).__name__} is not fitted yet. Call fit(X) on map descriptors first, "
            "or load a saved model with btel.load(path)."
        )


# -- declared parameter constraints ---------------------------------------------------------------
# Each estimator declares ``_parameter_constraints = {name: [constraint, ...]}`` once (the value must
# satisfy at least one), in the style of scikit-learn. The same table validates parameters in
# ``fit``, in :func:`btel.methods.make_method` (CLI ``--param``) and in the header of a model file.


class Interval:
    """Numbers of one kind in a range: ``Interval(int, 1, None)`` is an integer ≥ 1.

    Parameters
    ----------
    kind : {int, float}
        ``int`` accepts integers only (not bool); ``float`` accepts any real number (ints too).
    low, high : float or None
        Bounds (None: unbounded on that side). Infinite and NaN values are never accepted.
    closed : {'both', 'left', 'right', 'neither'}
        Which bounds are included.
    """

    def __init__(self, kind: type, low: float | None, high: float | None, closed: str = "both") -> None:
        self.kind, self.low, self.high, self.closed = kind, low, high, closed

    def accepts(self, value: Any) -> bool:
        if isinstance(value, bool) or not isinstance(value, numbers.Real):
            return False
        if self.kind is int and not isinstance(value, numbers.Integral):
            return False
        try:
            if not np.isfinite(float(value)):
                return False
        except (OverflowError, ValueError, TypeError):  # an integer beyond float range (10**400)
            return False
        left = self.closed in ("both", "left")
        right = self.closed in ("both", "right")
        if self.low is not None and (value < self.low or (value == self.low and not left)):
            return False
        if self.high is not None and (value > self.high or (value == self.high and not right)):
            return False
        return True

    def describe(self) -> str:
        # Integers in full (2147483647, not 2.14748e+09); a range of one value is that value.
        number = (lambda x: f"{int(x)}") if self.kind is int else (lambda x: f"{x:g}")
        if self.low is not None and self.low == self.high and self.closed == "both":
            return number(self.low)
        what = "an integer" if self.kind is int else "a number"
        lo = "" if self.low is None else f"{'≥' if self.closed in ('both', 'left') else '>'} {number(self.low)}"
        hi = "" if self.high is None else f"{'≤' if self.closed in ('both', 'right') else '<'} {number(self.high)}"
        bounds = " and ".join(b for b in (lo, hi) if b)
        return f"{what} {bounds}".strip()


class Options:
    """One of a fixed set of values (strings, usually)."""

    def __init__(self, *values: Any) -> None:
        self.values = tuple(values)

    def accepts(self, value: Any) -> bool:
        try:
            return any(value == v and type(value) is type(v) for v in self.values)
        except Exception:  # unhashable or odd comparisons: not one of ours
            return False

    def describe(self) -> str:
        return _one_of(self.values)


class String:
    """Any string (e.g. an address)."""

    def accepts(self, value: Any) -> bool:
        return isinstance(value, str)

    def describe(self) -> str:
        return "a string"


class DType:
    """A dtype given by name or as a numpy type (``'float16'``, ``np.float16``) among the allowed names."""

    def __init__(self, *names: str) -> None:
        self.names = tuple(names)

    def accepts(self, value: Any) -> bool:
        if isinstance(value, bool) or value is None:
            return False
        try:
            return np.dtype(value).name in self.names
        except (TypeError, ValueError, AttributeError):
            return False

    def describe(self) -> str:
        return _one_of(self.names)


def _one_of(values: tuple[Any, ...]) -> str:
    """``'auto'``, ``True or False``, ``one of 'a', 'b', 'c'``: a set of allowed values in words."""
    words = [repr(v) for v in values]
    return " or ".join(words) if len(words) <= 2 else "one of " + ", ".join(words)


class Budget:
    """A byte budget as :func:`btel.core.storage.parse_budget` reads it (None = no budget)."""

    def explain(self, value: Any) -> None:
        """Raise parse_budget's own message (it says how to write a budget)."""
        from .storage import parse_budget

        parse_budget(value)

    def accepts(self, value: Any) -> bool:
        from .storage import parse_budget

        if value is None:
            return True
        try:
            parse_budget(value)
        except InvalidParameterError:
            return False
        return True

    def describe(self) -> str:
        return "a byte budget such as 500000, '500KB' or '2MB' (or None)"


#: A seed: None or an integer in [0, 2**31 − 1] (what numpy, liblinear and faiss all accept: faiss
#: seeds are C ints).
RANDOM_STATE = [None, Interval(int, 0, 2**31 - 1)]
#: joblib / faiss worker counts: None, −1 (every core) or a positive integer.
N_JOBS = [None, Interval(int, -1, -1), Interval(int, 1, 4096)]
BOOLEAN = [Options(True, False)]
MAX_C = 1e10  # the largest C: far past any effect on L2-normalised rows; from ~1e100 the solvers overflow or never end


def _describe(constraint: Any) -> str:
    return "None" if constraint is None else constraint.describe()


def check_param(owner: str, name: str, value: Any, constraints: list[Any]) -> None:
    """Raise :class:`InvalidParameterError` unless ``value`` satisfies one of ``constraints``."""
    for constraint in constraints:
        if constraint is None:
            if value is None:
                return
        elif constraint.accepts(value):
            return
    for constraint in constraints:
        if hasattr(constraint, "explain"):
            constraint.explain(value)
    allowed = " or ".join(_describe(c) for c in constraints)
    text = repr(value)
    if len(text) > 80:
        text = text[:77] + "..."
    raise InvalidParameterError(f"{owner}: {name} must be {allowed}; got {text}.")


def check_params(estimator: Any, params: dict[str, Any] | None = None) -> None:
    """Validate ``params`` (default: ``estimator.get_params()``) against its declared constraints."""
    table = getattr(estimator, "_parameter_constraints", {})
    values = estimator.get_params(deep=False) if params is None else params
    owner = type(estimator).__name__
    for name, value in values.items():
        if name in table:
            check_param(owner, name, value, table[name])


# -- fitted state read from a model file ---------------------------------------------------------
def read_state_int(state: Any, key: str, minimum: int, maximum: int) -> int:
    """``state[key]`` as an int in [minimum, maximum], or :class:`ModelFileError` (a file is untrusted)."""
    value = state.get(key) if isinstance(state, dict) else None
    if isinstance(value, bool) or not isinstance(value, int) or not minimum <= value <= maximum:
        text = repr(value)
        raise ModelFileError(
            f"the model file's {key} = {text[:40]} is not an integer in [{minimum}, {maximum}]; "
            "the file is corrupt or was edited."
        )
    return int(value)


class Instance:
    """An instance of a given class (a nested estimator, e.g. OPQ's ``pq``)."""

    def __init__(self, cls: type) -> None:
        self.cls = cls

    def accepts(self, value: Any) -> bool:
        return isinstance(value, self.cls)

    def describe(self) -> str:
        return f"a {self.cls.__name__}"


def map_places(places: Any, n_rows: int) -> tuple[np.ndarray | None, int]:
    """A map's place labels checked: ``(labels, N)``, labels None when row i is place i (the common case)."""
    if places is None:
        if n_rows < 2:
            raise NotEnoughPlacesError(
                f"X has {n_rows} row (N = 1 place): an index needs at least 2 places. Fit on a longer route."
            )
        return None, n_rows
    labels, n_places = check_places(places, n_rows)
    if n_places == n_rows and np.array_equal(labels, np.arange(n_rows)):
        return None, n_places
    return labels, n_places
