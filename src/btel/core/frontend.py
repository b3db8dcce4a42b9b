"""What happens to a descriptor before a method sees it: delta → normalise → whiten (every method).

Every registered method owns one :class:`FrontEnd`, set by its parameters ``normalize``,
``whiten`` and ``delta``, fitted on the map in ``fit`` and applied to every query. Its arrays are
stored in the model file and counted by the storage rule, so :func:`btel.load` reproduces it.

- ``delta = w`` — **sequence (delta) descriptors** (Garg & Milford, RA-L 2020): frame j becomes the
  mean of frames j−w+1 … j minus the mean of frames j−2w+1 … j−w along the traverse. Causal (frame
  j uses frames ≤ j only), so it works online (:class:`FrontEndStream`). Before 2w frames have been
  seen the missing frames are taken to be copies of the first one (edge replication), so frame 0's
  delta is 0 and the early answers carry little information. A map given with ``places`` that
  restart (several traverses) is differenced traverse by traverse: a new traverse starts wherever
  the place label goes down. Queries must be consecutive frames of one traverse, in order — a
  method with a delta front end uses the query *sequence*, like SeqSLAM, and tables mark it so.
- ``normalize`` — ``'l2'`` (each row to unit length: cosine similarity, what NetVLAD-family global
  descriptors are made for), ``'power'`` (signed square root, then L2; the power-law
  normalisation of VLAD/RootSIFT), or ``'none'``. Applied to the frames before the delta and again
  to its result (a delta is compared by its direction).
- ``whiten = p`` — PCA whitening learnt on the (normalised) map: centre, project on the top p
  principal directions, divide by their standard deviations (scikit-learn ``PCA(whiten=True)``),
  then L2 again when ``normalize`` is not ``'none'``. Stores a d×p float32 matrix and a d float32
  mean (counted in the method's bytes).
- ``whiten = "shrink"`` — shrinkage whitening x ↦ (Σ + λI)^(-1/2)(x − μ), then L2 (λ = 1 × the
  mean eigenvalue; low rank, a 4-bit basis and a float16 mean, at most a quarter of the budget:
  :mod:`btel.core.shrink`).
  Keeps the dimension d; its arrays are stored and counted like PCA whitening's.

The default is ``normalize='l2'``: the front-ends experiment (``btel experiment front-ends``,
docs/results.md) measured it level with or above the raw descriptors, ``'power'`` and whitening.
"""

from __future__ import annotations

import functools
import inspect
import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .validation import Interval, Options
from ..exceptions import InvalidParameterError, ModelFileError
from .rows import (HUGE_NORM, NORMALIZATIONS, TINY_SQUARED_NORM, ScaledRows, delta_descriptors, normalize_rows,
                   one_row_squares, refuse_one_direction, row_norms, traverse_starts, warn_blank_rows)

__all__ = ["FrontEnd", "FrontEndStream", "ScaledRows", "delta_descriptors", "normalize_rows", "row_norms",
           "traverse_starts",
           "NORMALIZATIONS", "FRONT_END_CONSTRAINTS", "FRONT_END_MEANINGS",
           "with_front_end_parameters"]

#: Longest delta window (frames per half window).
MAX_DELTA = 1000

#: The constraints of the three front-end parameters every method declares.
FRONT_END_CONSTRAINTS: dict[str, list[Any]] = {
    "normalize": [Options(*NORMALIZATIONS)],
    "whiten": [None, Interval(int, 1, None), Options("shrink")],
    # A window of w frames keeps 2w frames per streamed query (and reads 2w·d values each frame):
    # windows are tens of frames; 1000 bounds what a model file can ask for.
    "delta": [None, Interval(int, 1, MAX_DELTA)],
}
#: What each front-end parameter does, in one sentence (``btel methods --params`` shows it).
FRONT_END_MEANINGS: dict[str, str] = {
    "normalize": "Row normalisation before anything else: l2, power (signed square root, then l2) or none.",
    "whiten": "PCA-whitening to this many dimensions, or shrink (shrinkage whitening); its arrays count in the "
              "bytes.",
    "delta": "Delta descriptors over W frames: mean of the last W minus the W before (uses the query sequence).",
}

# Rows transformed at a time (bounds the float64 temporaries on large, memory-mapped maps).
_CHUNK_ROWS = 65536


@dataclass
class FrontEnd:
    """The fitted front end of one model (module docstring for the steps and their order).

    Attributes
    ----------
    normalize : {'none', 'l2', 'power'}
    whiten : int or None
        p, whitened dimension (None: no whitening).
    delta : int or None
        w, delta window (None: single frames).
    mean_ : ndarray of shape (d,), float32, or None
        Whitening mean (only with ``whiten``).
    whitening_ : ndarray of shape (d, p), float32, or None
        Whitening matrix (principal directions divided by their standard deviations).
    """

    normalize: str = "none"
    whiten: int | None = None
    delta: int | None = None
    mean_: np.ndarray | None = field(default=None, repr=False)
    whitening_: np.ndarray | None = field(default=None, repr=False)
    #: The model's byte budget (sets the rank of ``whiten="shrink"``; not stored).
    budget: int | None = field(default=None, repr=False)
    #: ``whiten="shrink"``: mean (float16), basis levels (int8 d×r; stored 4-bit, or int8 as read from
    #: a file written before the 4-bit basis), basis scales and gains (float32 r).
    shrink_: tuple | None = field(default=None, repr=False)

    @classmethod
    def of(cls, estimator: Any) -> "FrontEnd":
        """The (unfitted) front end an estimator's ``normalize``/``whiten``/``delta`` parameters ask for
        (declared once for every method in :class:`btel.methods.base.PlaceLocalizer`)."""
        from .storage import budget_of

        return cls(estimator.normalize, estimator.whiten, estimator.delta, budget=budget_of(estimator))

    @property
    def is_identity(self) -> bool:
        return self.normalize == "none" and self.whiten is None and self.delta is None

    @property
    def plain_l2(self) -> bool:
        """True for the L2 normalisation alone (no delta, no whitening): a row is divided by its length."""
        return self.normalize == "l2" and self.delta is None and self.whiten is None

    @property
    def uses_sequence(self) -> bool:
        """True with delta descriptors: a query's answer depends on the frames before it."""
        return self.delta is not None

    # -- fit / transform ----------------------------------------------------------------------
    @property
    def checks_finite(self) -> bool:
        """True when :meth:`transform` with ``check_finite=True`` rejects NaN/inf itself (a normalising front end)."""
        return self.normalize != "none"

    def _frames(self, X: np.ndarray, starts: np.ndarray | None, check_finite: bool = False) -> np.ndarray:
        """Normalise, delta, normalise: everything before the whitening."""
        Z = normalize_rows(X, self.normalize, check_finite=check_finite, name="Q")
        if self.delta is not None:
            Z = normalize_rows(delta_descriptors(Z, self.delta, starts=starts), self.normalize)
        return Z

    def fit_transform(self, X: np.ndarray, starts: np.ndarray | None = None, *,
                      lazy: bool = False) -> np.ndarray | ScaledRows:
        """Learn the whitening (if any) on the map and return the transformed map, float32 (n, d_out).

        ``lazy``: the caller reads the map only by row selections and ``np.asarray`` of row blocks, so
        a plain L2 normalisation comes back as :class:`ScaledRows` (the map and one scale per row: no
        normalised copy of a map that may be most of memory).
        """
        refuse_one_direction(X, self.normalize)  # scaled copies of one row: one descriptor once normalised
        if lazy and self.plain_l2:
            return self.transform(X, starts, lazy=True)  # nothing to learn
        Z = self._frames(X, starts)
        if self.whiten == "shrink":
            from .shrink import fit_shrink, shrink_rank

            self.shrink_ = fit_shrink(Z, shrink_rank(Z.shape[1], Z.shape[0], self.budget))
            self._shrink_basis = None
        elif self.whiten is not None:
            from sklearn.decomposition import PCA

            self._check_whiten_rank(*Z.shape)
            pca = PCA(n_components=int(self.whiten), whiten=True, random_state=0).fit(Z)
            std = np.sqrt(np.maximum(pca.explained_variance_, 1e-12))
            self.mean_ = pca.mean_.astype(np.float32)
            self.whitening_ = np.ascontiguousarray((pca.components_.T / std).astype(np.float32))
        return self._whitened(Z)

    def _whitened(self, Z: np.ndarray) -> np.ndarray:
        if self.shrink_ is not None:
            from .shrink import apply_shrink

            mean, basis, scale, gains = self.shrink_
            if getattr(self, "_shrink_basis", None) is None:  # runtime cache of the dequantised basis
                self._shrink_basis = basis.astype(np.float32) * scale
            out = np.empty(Z.shape, dtype=np.float32)
            for start in range(0, Z.shape[0], _CHUNK_ROWS):
                out[start : start + _CHUNK_ROWS] = apply_shrink(Z[start : start + _CHUNK_ROWS], mean, basis, scale,
                                                                gains, self._shrink_basis)
            return normalize_rows(out, "none" if self.normalize == "none" else "l2")
        if self.whitening_ is None:
            return Z
        out = np.empty((Z.shape[0], self.whitening_.shape[1]), dtype=np.float32)
        for start in range(0, Z.shape[0], _CHUNK_ROWS):
            out[start : start + _CHUNK_ROWS] = (Z[start : start + _CHUNK_ROWS] - self.mean_) @ self.whitening_
        return normalize_rows(out, "none" if self.normalize == "none" else "l2")

    def one_row_scale(self, X: np.ndarray) -> float | None:
        """The factor that normalises one float32 query row, by Python arithmetic (µs count for one query).

        Parameters
        ----------
        X : ndarray of shape (1, d), float32

        Returns
        -------
        float or None
            1 / ‖x‖ (1.0 for a zero row, which stays zero); None where :meth:`transform`'s general path
            must run: not the plain L2 front end, not one float32 row, a NaN or inf (named there), or a
            row so short that its inverse length overflows float32 (scaled there in float64).
        """
        if not (self.plain_l2 and X.shape[0] == 1 and X.dtype == np.float32):
            return None
        squares = one_row_squares(X)
        # A zero float64 sum of squares of float32 values is a zero row: none underflows.
        if not (math.isfinite(squares) and (squares == 0.0 or squares >= TINY_SQUARED_NORM)):
            return None
        return 1.0 / math.sqrt(squares) if squares > 0 else 1.0

    def transform(self, X: np.ndarray, starts: np.ndarray | None = None, *, check_finite: bool = False,
                  lazy: bool = False) -> np.ndarray | ScaledRows:
        """Apply the fitted front end to validated descriptors (queries: one traverse, in order).

        ``check_finite``: reject NaN/inf in X while normalising (see :attr:`checks_finite`).
        ``lazy``: the caller only multiplies the rows by matrices, so a plain L2 normalisation
        comes back as :class:`ScaledRows` (no normalised copy of X).
        """
        plain_l2 = self.plain_l2
        scale = self.one_row_scale(X)
        # Queries (a map's rows come through fit_transform): a blank one gets a warning. One query's
        # scale is 1.0 when it is blank, so the common single query pays no extra pass for the check.
        if check_finite and (scale is None or scale == 1.0):
            warn_blank_rows(X)
        if scale is not None and not (lazy and scale * HUGE_NORM < 1.0):  # huge rows: normalised first
            # A Python float times a float32 array is float32 arithmetic (NEP 50): X * np.float32(scale).
            return ScaledRows(X, np.array([scale], dtype=np.float32)) if lazy else X * scale
        if self.is_identity:
            return X
        if lazy and plain_l2:
            norms = row_norms(X, check_finite=check_finite, name="Q")
            if norms.shape[0] == 1:  # one query: Python arithmetic beats three tiny numpy calls
                if not 0 < norms[0] * norms[0] < TINY_SQUARED_NORM and norms[0] <= HUGE_NORM:
                    inverse = 1.0 / norms[0] if norms[0] > 0 else 1.0
                    return ScaledRows(X, np.array([inverse], dtype=np.float32))
            elif not (((norms > 0) & (norms * norms < TINY_SQUARED_NORM)) | (norms > HUGE_NORM)).any():
                norms[norms == 0] = 1.0  # a zero row stays zero
                return ScaledRows(X, (1.0 / norms).astype(np.float32))
            # Rows so short that their inverse length overflows float32, or so long that their raw products
            # overflow it: normalised in float64 instead.
        return self._whitened(self._frames(X, starts, check_finite))

    def stream(self) -> "FrontEndStream":
        """A streaming version for one descriptor at a time (``btel localize --stream``)."""
        return FrontEndStream(self)

    # -- storage --------------------------------------------------------------------------------
    def arrays(self) -> dict[str, np.ndarray]:
        """The stored arrays (empty without whitening)."""
        if self.shrink_ is not None:
            return _shrink_arrays(self.shrink_)
        if self.whitening_ is None:
            return {}
        return {"frontend_mean": self.mean_, "frontend_whitening": self.whitening_}

    @property
    def nbytes(self) -> int:
        return int(sum(a.nbytes for a in self.arrays().values()))

    def planned_bytes(self, n_rows: int | None, n_features: int) -> int:
        """Bytes the fitted front end will store for ``n_rows`` map rows of d = ``n_features`` (known
        before fitting; the rows matter to shrinkage whitening only). A whitening rank the shape cannot
        give is refused here, before any budget arithmetic sized by it."""
        if self.whiten == "shrink":
            from .shrink import shrink_bytes, shrink_rank

            return shrink_bytes(n_features, shrink_rank(n_features, n_rows, self.budget))
        if self.whiten is not None and n_rows is not None:
            self._check_whiten_rank(int(n_rows), int(n_features))
        return 0 if self.whiten is None else int(n_features) * (int(self.whiten) + 1) * 4

    def _check_whiten_rank(self, n: int, d: int) -> None:
        if self.whiten > min(d, n - 1):
            raise InvalidParameterError(
                f"whiten = {self.whiten} needs at least {self.whiten + 1} map rows and descriptors of at least "
                f"{self.whiten} dimensions; got {n} rows of {d}. Use whiten ≤ {max(min(d, n - 1), 1)}."
            )

    def n_features_out(self, n_features: int) -> int:
        return int(n_features) if self.whiten in (None, "shrink") else int(self.whiten)

    def to_header(self) -> dict[str, Any]:
        return {"normalize": self.normalize, "whiten": self.whiten, "delta": self.delta}

    def describe(self) -> str:
        """One line: the front end's steps (and the shrinkage rank)."""
        white = self.whiten
        if self.shrink_ is not None:
            white = f"shrink (rank {self.shrink_[1].shape[1]}, {self.nbytes} B)"
        return f"normalize={self.normalize}, whiten={white}, delta={self.delta}"

    @classmethod
    def restore(cls, header: Any, arrays: dict[str, np.ndarray], n_features: int) -> "FrontEnd":
        """The front end recorded in a model file, checked against its arrays (ModelFileError if not)."""
        from .validation import check_param

        if not isinstance(header, dict) or set(header) != {"normalize", "whiten", "delta"}:
            raise ModelFileError("the model file's front end is missing or malformed.")
        for name, constraints in FRONT_END_CONSTRAINTS.items():
            try:
                check_param("front end", name, header[name], constraints)
            except InvalidParameterError as exc:
                raise ModelFileError(f"the model file's front end is invalid: {exc}") from exc
        front = cls(header["normalize"], header["whiten"], header["delta"])
        if front.whiten == "shrink":
            front.shrink_ = _restore_shrink(arrays, n_features)
            return front
        mean, matrix = arrays.pop("frontend_mean", None), arrays.pop("frontend_whitening", None)
        if front.whiten is None:
            if mean is not None or matrix is not None:
                raise ModelFileError("the model file holds a whitening matrix but its header says no whitening.")
            return front
        p = int(front.whiten)
        if mean is None or matrix is None or mean.shape != (n_features,) or matrix.shape != (n_features, p) \
                or mean.dtype != np.float32 or matrix.dtype != np.float32:
            raise ModelFileError(
                f"the model file's whitening arrays do not match d = {n_features}, p = {p} (float32 expected)."
            )
        if not (np.isfinite(mean).all() and np.isfinite(matrix).all()):
            raise ModelFileError("the model file's whitening arrays contain NaN or infinite values.")
        front.mean_, front.whitening_ = mean, matrix
        return front


#: Names of the stored arrays of ``whiten="shrink"``; the basis is either the 4-bit packed one
#: (``..._basis4``, what fit writes) or the int8 one of files written before it (``..._basis``).
_SHRINK_ARRAYS = ("frontend_shrink_mean", "frontend_shrink_basis4", "frontend_shrink_scale", "frontend_shrink_gains")
_SHRINK_BASIS_INT8 = "frontend_shrink_basis"


def _shrink_arrays(shrink: tuple) -> dict[str, np.ndarray]:
    """The stored arrays of fitted shrinkage: the basis packed 4-bit when its levels allow, else int8."""
    from .shrink import SHRINK_BASIS_BITS, pack_basis

    mean, basis, scale, gains = shrink
    if basis.size == 0 or int(np.abs(basis).max()) <= 2 ** (SHRINK_BASIS_BITS - 1) - 1:
        return dict(zip(_SHRINK_ARRAYS, (mean, pack_basis(basis), scale, gains)))
    # Read from a file written with the int8 basis: written back as it was, without loss.
    return {_SHRINK_ARRAYS[0]: mean, _SHRINK_BASIS_INT8: basis, _SHRINK_ARRAYS[2]: scale, _SHRINK_ARRAYS[3]: gains}


def _restore_shrink(arrays: dict[str, np.ndarray], n_features: int) -> tuple:
    """The shrinkage arrays of a model file, checked (ModelFileError if not as fit writes them)."""
    from .shrink import unpack_basis

    old = arrays.pop(_SHRINK_BASIS_INT8, None)
    parts = [arrays.pop(name, None) for name in _SHRINK_ARRAYS]
    if old is not None and parts[1] is not None:
        raise ModelFileError("the model file holds both a 4-bit and an int8 shrinkage basis; it was not written by "
                             "btel. Refit and save the model.")
    packed = old is None
    if not packed:
        parts[1] = old
    if any(p is None for p in parts):
        raise ModelFileError("the model file says whiten='shrink' but lacks its arrays "
                             f"({', '.join(n for n, p in zip(_SHRINK_ARRAYS, parts) if p is None)}).")
    mean, basis, scale, gains = parts
    if basis.ndim != 2 or scale.ndim != 1:
        raise ModelFileError("the model file's shrinkage basis is not a matrix or its scales not a vector.")
    r = scale.shape[0]
    shape, dtype = ((r, (n_features + 1) // 2), np.uint8) if packed else ((n_features, r), np.int8)
    if mean.shape != (n_features,) or mean.dtype != np.float16 or basis.shape != shape \
            or basis.dtype != dtype or gains.shape != (r,) \
            or scale.dtype != np.float32 or gains.dtype != np.float32:
        raise ModelFileError(f"the model file's shrinkage arrays do not match d = {n_features} (float16 mean, "
                             f"{'4-bit r×⌈d/2⌉ uint8' if packed else 'int8 d×r'} basis, float32 scales and gains "
                             "expected).")
    if packed:
        basis = unpack_basis(basis, n_features)
    if not all(np.isfinite(a).all() and float(np.abs(a).max(initial=0)) <= 1e6 for a in (mean, scale, gains)):
        raise ModelFileError("the model file's shrinkage arrays contain NaN, infinite or out-of-range values.")
    return mean, basis, scale, gains


class FrontEndStream:
    """One descriptor at a time through a fitted :class:`FrontEnd` (causal; keeps the last 2w frames).

    ``update(x)`` takes a (1, d) float32 row and returns the transformed (1, d_out) row, from the
    first frame on; before 2w frames the missing ones are copies of the first (as in the batch
    transform, so streaming equals :meth:`FrontEnd.transform` row by row). :meth:`reset` starts a
    new traverse.
    """

    def __init__(self, front: FrontEnd) -> None:
        self.front = front
        self._history: list[np.ndarray] = []

    def reset(self) -> None:
        self._history = []

    def update(self, x: np.ndarray) -> np.ndarray:
        front = self.front
        z = normalize_rows(np.asarray(x, dtype=np.float32).reshape(1, -1), front.normalize)
        if front.delta is not None:
            w = int(front.delta)
            if not self._history:
                self._history = [z[0]] * (2 * w)
            self._history = self._history[1:] + [z[0]]
            frames = np.asarray(self._history, dtype=np.float64)
            d = (frames[w:].mean(axis=0) - frames[:w].mean(axis=0)).astype(np.float32)
            z = normalize_rows(d.reshape(1, -1), front.normalize)
        return front._whitened(z)


def with_front_end_parameters(init: Any, defaults: dict[str, Any]) -> Any:
    """``init`` taking the front end's parameters too (keyword-only, with ``defaults``), stored as attributes.

    Its signature lists them, so scikit-learn's ``get_params`` (which reads the signature of
    ``__init__``) and ``clone`` treat them as the method's own parameters.
    """
    signature = inspect.signature(init)
    clash = set(defaults) & set(signature.parameters)
    if clash:
        raise TypeError(f"{init.__qualname__} declares {sorted(clash)}: the front end's parameters are "
                        "declared once, in PlaceLocalizer.front_end_defaults.")
    front = [inspect.Parameter(name, inspect.Parameter.KEYWORD_ONLY, default=value)
             for name, value in defaults.items()]

    @functools.wraps(init)
    def __init__(self: Any, *args: Any, **params: Any) -> None:
        values = {name: params.pop(name, default) for name, default in defaults.items()}
        init(self, *args, **params)
        for name, value in values.items():
            setattr(self, name, value)

    __init__.__signature__ = signature.replace(  # type: ignore[attr-defined]
        parameters=[*signature.parameters.values(), *front])
    return __init__
