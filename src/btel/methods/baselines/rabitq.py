"""RaBitQ (Gao & Long, SIGMOD 2024; extended to B bits per dimension, Gao et al. 2025) under a byte budget.

Fit: rotate the (front-end transformed) map by a seeded random orthogonal transform and keep D of
its coordinates (a d×D map with orthonormal columns), subtract the mean of the rotated map (the
centroid c) and quantise each residual r = x − c: one sign bit per dimension, plus B − 1 magnitude
bits when B > 1, plus the per-row correction factors that make RaBitQ's distance estimate unbiased
(‖r‖², ‖r‖ / ⟨x̄, r/‖r‖⟩, and for B > 1 an error bound and two factors of the extra bits). The query
is rotated the same way and quantised to ``query_bits`` bits per dimension (faiss ``IndexRaBitQ``'s
``qb``; RaBitQ's paper quantises queries to 4 bits, the default 8 answers as the float query does
within noise, 4–30 times faster; 0 keeps it in float): a linear scan of the
estimated L2 distances, score = −estimate. Files that record no ``query_bits`` kept the query in
float and still do.

Rotation (``rotation``): ``'hadamard'`` (default) — random sign flips and fast Walsh–Hadamard
transforms (:class:`~btel.methods.baselines.hadamard.HadamardRotation`, the family of the RaBitQ
authors' library's default rotator): exactly orthogonal, O(d log d) per row, nothing d × d; ``'qr'``
— the Q of a QR factorisation of a d×D Gaussian matrix, O(d·D²) at every fit and load (model files
that record no rotation used it). Evidence: ``docs/decisions/rabitq.md``.

Storage (the one storage rule of docs/guide/concepts.md): the rotation is regenerated from the seed (0 bytes, as LSH's
projection and btel-codes' codewords); everything learned is counted at its stored width:

- ``signs``: n_rows × ⌈D/8⌉ bytes; ``ex_codes`` (B > 1): n_rows × ⌈D(B−1)/8⌉ bytes;
- ``factors``: n_rows × 2 values (B = 1) or × 5 (B > 1);
- ``centroid``: D values.

Factors and centroid are float16 when the front end L2-normalises its output (``normalize`` is
not ``'none'``: every value is then bounded by a few times √D), else float32. The model is always
searched from these stored arrays (at fit as after :func:`btel.load`), so rounding is part of
the measured method, and a model file never reaches faiss' own deserialiser: the codes are
re-assembled from checked arrays (no value in them is an index, so any bytes are safe).

Budget rule (fixed before any measurement): first dimensions, then bits — D is the largest
multiple of 8 up to d (or d itself) that fits with B = 1; once D = d fits, B is the largest in
1 … 9 that fits. A rotation to D < d keeps only a D-dimensional random view of the map, while
more bits per dimension only refine what is kept, so dimensions are bought first. ``dim`` or
``nbits`` pins that part; the rule chooses the rest. Without a budget: D = d, B = 1 (the original
RaBitQ). Nothing fits (D = 8, B = 1): :class:`~btel.exceptions.BudgetTooSmallError`.

Against asymmetric LSH at the same budget: ``docs/decisions/rabitq.md``.
"""

from __future__ import annotations

from typing import Any

import faiss
import numpy as np

from ...core.storage import spent_text
from ...core.validation import N_JOBS, RANDOM_STATE, Interval, Options, read_state_int
from ..base import ArraySpec
from ...exceptions import BTELError, InvalidDescriptorsError, InvalidParameterError, ModelFileError
from ._common import (MAX_NORM, _RowLocalizer, check_model_values, index_search, negated_distances,
                      raise_budget_too_small, recorded_kind)
from .hadamard import DenseTransform, HadamardRotation

__all__ = ["RaBitQLocalizer", "rotation_matrix", "make_rotation", "ROTATIONS"]

#: Most bits per dimension faiss' RaBitQ quantiser takes.
MAX_NBITS = 9
#: Most bits per dimension of the quantised query (faiss' ``qb``).
MAX_QUERY_BITS = 8
#: The rotations ``rotation`` takes (module docstring); files without one used the last.
ROTATIONS = ("hadamard", "qr")


def rotation_matrix(n_features: int, dim: int, seed: int) -> np.ndarray:
    """The d×D matrix with orthonormal columns of a seed (QR of numpy PCG64 Gaussians), float32.

    Regenerated from the seed, not stored. Columns are sign-fixed (R's diagonal made positive)
    so that the matrix is the unique Q of its Gaussian draw.
    """
    rng = np.random.default_rng(int(seed))
    q, r = np.linalg.qr(rng.standard_normal((int(n_features), int(dim))))
    signs = np.where(np.diag(r) < 0, -1.0, 1.0)
    return np.ascontiguousarray(q * signs, dtype=np.float32)


def make_rotation(n_features: int, dim: int, seed: int, kind: str = "hadamard") -> Any:
    """The rotation of a seed, d features to D coordinates: an object with ``apply(X)`` ((n, d) → (n, D)
    float32) and ``matrix()`` (the d × D float32 matrix with orthonormal columns)."""
    if kind == "hadamard":
        return HadamardRotation(n_features, dim, seed)
    if kind == "qr":
        return DenseTransform(rotation_matrix(n_features, dim, seed), "qr")
    raise InvalidParameterError(f"rotation must be one of {ROTATIONS}; got {kind!r}.")


def _dims(n_features: int) -> list[int]:
    """Every D the budget rule considers, increasing: multiples of 8 below d, then d."""
    return [D for D in range(8, n_features, 8)] + [n_features]


class RaBitQLocalizer(_RowLocalizer):
    """RaBitQ codes of the map (seeded rotation, D dimensions × B bits) filling the budget; faiss search.

    Parameters
    ----------
    budget : int or str, optional
        Bytes (or ``"64KB"``); D and B by the rule in the module docstring.
    dim : int, optional
        Pin D, the rotated dimensions (at most d after the front end).
    nbits : int, optional
        Pin B, bits per dimension (1 … 9).
    rotation : {'hadamard', 'qr'}
        The seeded rotation: sign flips and fast Walsh–Hadamard transforms, O(d log d) per row
        (default), or the QR of a Gaussian d × D matrix, O(d·D²) at every fit and load.
    query_bits : int, default 8
        Bits per dimension of the rotated query in faiss' scan (0 … 8); 0 keeps it in float, which
        scans 4–30 times slower for the same answers within noise (docs/decisions/rabitq.md).
    random_state : int or None
        Seed of the rotation; None draws one. The seed used is recorded (``seed_``) and saved.
    normalize, whiten, delta
        The front end (:mod:`btel.core.frontend`).
    n_jobs : int, optional
        faiss threads for searching.

    Attributes
    ----------
    dim_, nbits_, seed_ : int
    signs_ : ndarray of shape (n_rows, ceil(dim_ / 8)), uint8
    ex_codes_ : ndarray of shape (n_rows, ceil(dim_ * (nbits_ - 1) / 8)), uint8, or None (B = 1)
    factors_ : ndarray of shape (n_rows, 2 or 5), float16 or float32
    centroid_ : ndarray of shape (dim_,), float16 or float32
    rotation_ : object
        :func:`make_rotation`'s, regenerated from ``seed_`` (not stored): ``rotation_.apply(X)`` is
        X M, ``rotation_.matrix()`` the (n_features, dim_) float32 matrix M.
    n_places_, n_features_in_ : int
    row_places_ : ndarray of shape (n_rows,) or None
    fit_time_ : float

    Examples
    --------
    >>> import numpy as np
    >>> X = np.random.default_rng(0).normal(size=(100, 32)).astype(np.float32)
    >>> RaBitQLocalizer(budget=3000).fit(X).predict(X[:3]).tolist()
    [0, 1, 2]
    """

    label = "rabitq"
    _fit_reads_row_blocks = True  # _fit_rows reads row blocks: an L2 front end hands it the map unscaled
    _float32_distances = True  # a map of tiny rows is refused at fit (_common.MIN_NORM)
    _parameter_constraints = {
        "dim": [None, Interval(int, 1, None)],
        "nbits": [None, Interval(int, 1, MAX_NBITS)],
        "rotation": [Options(*ROTATIONS)],
        "query_bits": [Interval(int, 0, MAX_QUERY_BITS)],
        "random_state": RANDOM_STATE,
        "n_jobs": N_JOBS,
    }

    def __init__(self, *, budget: int | str | None = None, dim: int | None = None, nbits: int | None = None,
                 rotation: str = "hadamard", query_bits: int = 8, random_state: int | None = 0,
                 n_jobs: int | None = None) -> None:
        self.budget = budget
        self.dim = dim
        self.nbits = nbits
        self.rotation = rotation
        self.query_bits = query_bits
        self.random_state = random_state
        self.n_jobs = n_jobs

    # -- configuration -------------------------------------------------------------------------
    def _value_dtype(self) -> np.dtype:
        """float16 when the front end's rows are unit length (bounded factors), else float32."""
        return np.dtype(np.float32 if self.normalize == "none" else np.float16)

    @staticmethod
    def _n_factors(nbits: int) -> int:
        return 2 if nbits == 1 else 5

    def planned_bytes(self, n_rows: int, n_features: int, *, dim: int, nbits: int) -> int:
        """Codes, factors and centroid of D dimensions × B bits for ``n_rows`` rows (no row table); the
        seeded rotation of the ``n_features`` dimensions is not stored."""
        width = self._value_dtype().itemsize
        per_row = -(-dim // 8) + -(-dim * (nbits - 1) // 8) + self._n_factors(nbits) * width
        return n_rows * per_row + dim * width

    def choose_config(self, n_rows: int, n_features: int, budget: int | None,
                      reserved: int = 0) -> tuple[int, int]:
        """(D, B), the rotated dimensions and bits per dimension ``fit`` uses (module docstring)."""
        if self.dim is not None and self.dim > n_features:
            raise InvalidParameterError(f"dim = {self.dim} exceeds the descriptor dimension {n_features} "
                                        f"(after the front end); use dim ≤ {n_features}.")
        dims = [int(self.dim)] if self.dim is not None else _dims(n_features)
        bits = [int(self.nbits)] if self.nbits is not None else list(range(1, MAX_NBITS + 1))
        if budget is None:
            return dims[-1], bits[0]

        def fits(D: int, B: int) -> bool:
            return reserved + self.planned_bytes(n_rows, n_features, dim=D, nbits=B) <= budget

        fitting = [D for D in dims if fits(D, bits[0])]
        if not fitting:
            minimum = reserved + self.planned_bytes(n_rows, n_features, dim=dims[0], nbits=bits[0])
            raise_budget_too_small("RaBitQ", budget, minimum,
                                   f"D = {dims[0]} dimensions × {bits[0]} bit(s) for {n_rows} rows + "
                                   f"{self._n_factors(bits[0])} {self._value_dtype().name} factors each")
        D = max(fitting)
        return D, max(B for B in bits if fits(D, B))

    def _check_plan(self, n_rows: int, n_features_out: int, budget: int | None, reserved: int) -> None:
        self.choose_config(n_rows, n_features_out, budget, reserved)

    def budget_saturated(self) -> bool:
        """True when D and B are the largest the parameters allow (a larger budget gives the same model)."""
        d = self.rotation_.n_features
        return self.dim_ == (self.dim or d) and self.nbits_ == (self.nbits or MAX_NBITS)

    # -- fitting -------------------------------------------------------------------------------
    def _fit_rows(self, X: np.ndarray, budget: int | None, reserved: int) -> None:
        n_rows, d = X.shape
        D, B = self.choose_config(n_rows, d, budget, reserved)
        seed = int(self.random_state) if self.random_state is not None else \
            int(np.random.default_rng().integers(0, 2**31 - 1))
        self.dim_, self.nbits_, self.seed_ = D, B, seed
        self.rotation_ = make_rotation(d, D, seed, self.rotation)
        # The rotated map in row blocks, twice (its mean, then the codes): never a rotated copy of the map.
        step = max(1, (1 << 22) // max(d, D, 1))
        blocks = range(0, n_rows, step)
        total = np.zeros(D)
        for a in blocks:
            total += self.rotation_.apply(X[a : a + step]).sum(axis=0, dtype=np.float64)
        dtype = self._value_dtype()
        self.centroid_ = (total / n_rows).astype(dtype)
        index = self._empty_index()
        for a in blocks:
            index.add(np.ascontiguousarray(self.rotation_.apply(X[a : a + step])))
        codes = faiss.vector_to_array(index.codes).reshape(n_rows, index.code_size)
        s, e = -(-D // 8), -(-D * (B - 1) // 8)
        factors = (codes[:, s : s + 12] if B > 1 else codes[:, s:]).copy().view(np.float32)
        if B > 1:
            factors = np.hstack([factors, codes[:, s + 12 + e :].copy().view(np.float32)])
        with np.errstate(over="ignore"):
            stored = factors.astype(dtype)
        # What load refuses (check_model_values) is refused here, with the map's fix.
        if not all(np.isfinite(a).all() and float(np.abs(a).max(initial=0)) <= MAX_NORM
                   for a in (stored, self.centroid_)):
            raise InvalidDescriptorsError(
                f"RaBitQ's correction factors of this map overflow their stored {dtype.name} or exceed "
                f"{MAX_NORM:.0e} (they hold squared row lengths: rows longer than about 1e9 after the "
                "front end are too long). Scale the descriptors down (normalize='none' stores float32 "
                "factors).")
        self.signs_ = np.ascontiguousarray(codes[:, :s])
        self.ex_codes_ = np.ascontiguousarray(codes[:, s + 12 : s + 12 + e]) if B > 1 else None
        self.factors_ = stored
        self._index = self._build_index()

    def _empty_index(self) -> Any:
        """A trained, empty faiss index of the model's D, B and (stored) centroid; layout checked."""
        D, B = int(self.dim_), int(self.nbits_)
        index = faiss.IndexRaBitQ(D, faiss.METRIC_L2, B)
        expected = -(-D // 8) + -(-D * (B - 1) // 8) + 4 * self._n_factors(B)
        if index.code_size != expected:
            raise BTELError(f"this faiss ({faiss.__version__}) lays out RaBitQ codes in "
                            f"{index.code_size} bytes, not {expected}; btel's RaBitQ needs faiss-cpu "
                            "≥ 1.13.2 (verified on 1.15.1).")
        index.qb = int(self.query_bits)  # 0: the query stays in float
        faiss.copy_array_to_vector(self.centroid_.astype(np.float32), index.center)
        index.is_trained = True
        return index

    def _build_index(self) -> Any:
        """The faiss index re-assembled from the stored arrays.

        Its codes are signs | factors | ex-codes | ex-factors, row by row.
        """
        index = self._empty_index()
        f = np.ascontiguousarray(self.factors_, dtype=np.float32)
        if self.nbits_ == 1:
            parts = [self.signs_, f.view(np.uint8)]
        else:
            parts = [self.signs_, np.ascontiguousarray(f[:, :3]).view(np.uint8), self.ex_codes_,
                     np.ascontiguousarray(f[:, 3:]).view(np.uint8)]
        index.add_sa_codes(np.ascontiguousarray(np.hstack(parts)))
        return index

    # -- inference -----------------------------------------------------------------------------
    def _search_rows(self, Q: np.ndarray, k: int,
                     scores: bool = True) -> tuple[np.ndarray | None, np.ndarray]:
        rotated = np.ascontiguousarray(self.rotation_.apply(Q))
        dist, rows = index_search(self._index, rotated, k)
        return negated_distances(dist) if scores else None, rows.astype(np.int64, copy=False)

    def summary(self) -> str:
        """One line: D, B, seed, factor width, the bytes against the budget and the front end."""
        return (f"rabitq: {self.dim_} rotated dimensions × {self.nbits_} bit(s), {self.rotation} rotation from "
                f"seed {self.seed_} (0 B), {self.factors_.dtype.name} factors, "
                f"{f'{self.query_bits}-bit' if self.query_bits else 'float'} queries; {spent_text(self)}; "
                f"front end {self.front_end_.describe()}")

    # -- storage and files ---------------------------------------------------------------------
    def _model_arrays(self) -> dict[str, np.ndarray]:
        arrays = {"signs": self.signs_, "factors": self.factors_, "centroid": self.centroid_}
        if self.ex_codes_ is not None:
            arrays["ex_codes"] = self.ex_codes_
        return arrays

    def _model_state(self) -> dict[str, Any]:
        return {"dim": int(self.dim_), "nbits": int(self.nbits_), "seed": int(self.seed_),
                "rotation": self.rotation, "query_bits": int(self.query_bits)}

    def _model_specs(self, state: dict[str, Any], d: int) -> dict[str, ArraySpec]:
        D = read_state_int(state, "dim", 1, d)
        B = read_state_int(state, "nbits", 1, MAX_NBITS)
        read_state_int(state, "seed", 0, 2**63 - 1)
        recorded_kind(state, "rotation", ROTATIONS, "RaBitQ")
        if "query_bits" in state:
            read_state_int(state, "query_bits", 0, MAX_QUERY_BITS)
        dtype = self._value_dtype()
        return {"signs": ArraySpec((None, -(-D // 8)), np.uint8),
                "factors": ArraySpec((None, self._n_factors(B)), dtype),
                "centroid": ArraySpec((D,), dtype),
                "ex_codes": ArraySpec((None, -(-D * (B - 1) // 8)), np.uint8, required=B > 1)}

    def _n_rows(self) -> int:
        return int(self.signs_.shape[0])

    def _restore_model(self, arrays: dict[str, np.ndarray], state: dict[str, Any]) -> None:
        check_model_values(arrays, ("factors", "centroid"), "RaBitQ")
        B = int(state["nbits"])
        n_rows = arrays["signs"].shape[0]
        if arrays["factors"].shape[0] != n_rows or (B > 1 and arrays["ex_codes"].shape[0] != n_rows) \
                or (B == 1 and "ex_codes" in arrays):
            raise ModelFileError("the RaBitQ model file's signs, factors and ex_codes do not have one row "
                                 "per map row each (or it holds ex_codes for 1-bit codes).")
        self.dim_, self.nbits_, self.seed_ = int(state["dim"]), B, int(state["seed"])
        self.signs_ = np.ascontiguousarray(arrays["signs"])
        self.ex_codes_ = np.ascontiguousarray(arrays["ex_codes"]) if B > 1 else None
        self.factors_ = np.ascontiguousarray(arrays["factors"])
        self.centroid_ = np.ascontiguousarray(arrays["centroid"])
        # The rotation the codes were made with: files that record none used the QR one.
        self.rotation = recorded_kind(state, "rotation", ROTATIONS, "RaBitQ", self.rotation)
        # Files that record no query_bits scanned with the query in float: they answer as they did.
        self.query_bits = int(state["query_bits"]) if "query_bits" in state else 0
        self.rotation_ = make_rotation(self.front_end_.n_features_out(int(state["n_features_in"])),
                                       self.dim_, self.seed_, self.rotation)
        self._index = self._build_index()
