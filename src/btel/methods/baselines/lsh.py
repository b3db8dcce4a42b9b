"""Seeded sign random projections (locality-sensitive hashing, Charikar 2002) filling the byte budget.

Fit: project every (front-end transformed) map row x_i by the seed's projection R (d → P), store the
P signs of x_i R packed 8 to a byte. R is regenerated from the recorded seed at fit and at load
(anything regenerated from a recorded seed costs 0 bytes), so the model is the codes plus, with
``center=True``, the map mean at float16.

Projection (``projection``): ``'hadamard'`` (default) — random sign flips and fast Walsh–Hadamard
transforms, d padded to a power of two D, three rounds per block of D hyperplanes
(:mod:`~btel.methods.baselines.hadamard`): within a block the hyperplanes are orthogonal, which
lowers the variance of the angle the P signs estimate (super-bit LSH, Ji et al. 2012); a row costs
3·D·Σ factors multiply-adds per block (Hadamard factors of at most 64) and a block 3·D signs of
memory. ``'orthogonal'`` — the seed's Gaussian d × P matrix with every block of d columns
orthonormalised by QR (O(d·P²) work at every fit and load, d·P floats of memory; the default before,
read for files written with it). ``'gaussian'`` — i.i.d. Gaussian hyperplanes (files that record no
projection used it). Evidence: ``docs/decisions/lsh-projection.md``.

Scoring (``scoring``): ``'asymmetric'`` (default) — the query is projected, not binarised:
score_i = (qR) · sign(x_i R) (Gordo et al. 2014), computed from the packed codes, never from an
unpacked copy (:mod:`~btel.methods.baselines.signscan`: lookup tables for a few queries, blocks of
rows unpacked to ±1 for batches). ``'hamming'`` — the query is binarised too and the codes are
searched by Hamming distance (faiss ``knn_hamming``); score = −distance.

Budget rule: P = ⌊8·(budget − reserved − mean bytes) / n_rows⌋ bits per row (at least 8), at most
16·d (the row's size at float16; the score is then within noise of the cosine it estimates, and
``budget_saturated()`` / ``unused_budget()`` say the cap stopped it); no budget: P =
:data:`DEFAULT_BITS`; ``n_bits`` pins P. Codes are one stream of n_rows·P bits: the (n_rows, P/8)
byte matrix when 8 divides P, else a flat byte array (the state records n_rows). The planner
needs only the shapes, so ``fit`` refuses a budget before it transforms the map.

Front end: plain cosine by default (``center=False``): with bits to spare the codes approach
cosine brute force. ``center=True`` subtracts the map mean (d float16, counted) before the
projection — centred cosine, another search. ``center='auto'``: when the rows lie in a cone
(‖mean row‖ ≥ :data:`CENTER_CONE` × RMS length) and the mean costs ≤ :data:`CENTER_SHARE` of the
budget. :meth:`LSHLocalizer.effective_bits` counts an uncentred sign bit at
:func:`sign_bit_entropy` of the cone ratio c: a random hyperplane leaves a share
Φ(−|z|·c/√(1 − c²)), z ~ N(0, 1), of the rows on its minority side. Evidence:
``docs/decisions/lsh-centring.md``.
"""

from __future__ import annotations

from typing import Any

import faiss
import numpy as np

from ...core.rows import mean_and_rms
from ...core.storage import budget_of, spent_text
from ...core.validation import N_JOBS, RANDOM_STATE, Interval, Options, read_state_int
from ..base import ArraySpec
from ...exceptions import BudgetTooSmallError, InvalidParameterError, ModelFileError
from . import signscan
from ._common import _RowLocalizer, check_magnitude, check_model_values, raise_budget_too_small, recorded_kind
from .hadamard import DenseTransform, SignedHadamard

__all__ = ["LSHLocalizer", "projection_matrix", "make_projection", "PROJECTIONS", "code_bytes", "dense_codes",
           "row_codes", "cone_ratio", "sign_bit_entropy"]

#: Without a budget, codes have this many bits.
DEFAULT_BITS = 256
#: Most bits per row the budget rule gives per dimension (16·d bits: the row's size at float16).
MAX_BITS_PER_DIMENSION = 16
#: Most bits per row at all (``n_bits`` and model files).
MAX_BITS = 1 << 16
#: ``center='auto'`` centres when the float16 mean costs at most this share of the budget ...
CENTER_SHARE = 1 / 8
#: ... and the map's rows lie in a cone: ‖mean row‖ at least this × their RMS length (module docstring).
CENTER_CONE = 0.5
#: Values projected at a time when the map is coded: 4 MB of float32.
BLOCK_VALUES = 1 << 20
#: Map rows repacked at a time between the row matrix and the dense stream.
_BLOCK_ROWS = 4096

#: The projections ``projection`` takes (module docstring); files without one used the last.
PROJECTIONS = ("hadamard", "orthogonal", "gaussian")


def make_projection(n_features: int, n_bits: int, seed: int, kind: str = "hadamard") -> Any:
    """The projection of a seed: an object with ``apply(X) -> X R`` ((n, d) → (n, P) float32) and
    ``matrix()`` (R, (d, P) float32).

    ``'hadamard'``: :class:`~btel.methods.baselines.hadamard.SignedHadamard` (nothing d × P is held
    unless it is small); ``'orthogonal'`` and ``'gaussian'``: the d × P matrix of :func:`projection_matrix`.
    """
    if kind == "hadamard":
        return SignedHadamard(n_features, n_bits, seed)
    return DenseTransform(projection_matrix(n_features, n_bits, seed, kind), kind)


def projection_matrix(n_features: int, n_bits: int, seed: int, kind: str = "gaussian") -> np.ndarray:
    """The d×P projection of a seed as a float32 matrix.

    ``'gaussian'``: numpy's PCG64 ``standard_normal`` (d, P); ``'orthogonal'``: that matrix with each
    block of d consecutive columns orthonormalised (QR, signs fixed so the block is Haar-distributed)
    and scaled by √d; ``'hadamard'``: :class:`~btel.methods.baselines.hadamard.SignedHadamard`'s matrix.

    Deterministic for a given numpy bit generator, so it is regenerated rather than stored (up to the
    last bits of the platform's QR or matrix products, which move a query's projection, not the
    stored signs).
    """
    if kind not in PROJECTIONS:
        raise InvalidParameterError(f"projection must be one of {PROJECTIONS}; got {kind!r}.")
    if kind == "hadamard":
        return SignedHadamard(n_features, n_bits, seed).matrix()
    rng = np.random.default_rng(int(seed))
    gaussian = rng.standard_normal((int(n_features), int(n_bits)), dtype=np.float32)
    if kind == "gaussian":
        return gaussian
    d = int(n_features)
    out = np.empty_like(gaussian)
    for start in range(0, gaussian.shape[1], d):
        q, r = np.linalg.qr(gaussian[:, start : start + d].astype(np.float64))
        # Sign-fixed Q is Haar-distributed; √d gives its columns the Gaussian columns' typical length.
        out[:, start : start + d] = q * (np.sign(np.diag(r)) * np.sqrt(d))
    return out

def cone_ratio(X: Any, moments: tuple[np.ndarray, float] | None = None) -> float:
    """‖mean row‖ / RMS row length of ``X`` (n_rows, d), or of its ``moments`` (:func:`mean_and_rms`): 0 for
    rows spread around the origin, 1 when all are equal; for unit rows its square is the mean cosine."""
    mean, rms = mean_and_rms(X) if moments is None else moments
    return float(np.linalg.norm(mean) / rms) if rms > 0 else 0.0


def sign_bit_entropy(cone: float) -> float:
    """Expected entropy (bits) of one uncentred random-hyperplane sign bit on unit rows in a cone.

    Parameters
    ----------
    cone : float in [0, 1]
        :func:`cone_ratio` of the L2-normalised rows.

    Returns
    -------
    float in [0, 1]
        E_z[H₂(Φ(−|z|·c/√(1 − c²)))], z ~ N(0, 1) (module docstring): 1 for rows spread around the
        origin, 0 when every row is the same.
    """
    from scipy import integrate, stats

    c = min(max(float(cone), 0.0), 1.0)
    if c >= 1.0:
        return 0.0
    slope = c / np.sqrt(1.0 - c * c)

    def entropy(z: float) -> float:
        p = float(stats.norm.cdf(-z * slope))
        if p <= 0.0:
            return 0.0
        return 2.0 * float(stats.norm.pdf(z)) * -(p * np.log2(p) + (1.0 - p) * np.log2(1.0 - p))

    return float(min(1.0, integrate.quad(entropy, 0.0, np.inf)[0]))


def code_bytes(n_rows: int, n_bits: int) -> int:
    """Stored bytes of n_rows codes of n_bits: one dense stream, ⌈n_rows·n_bits / 8⌉."""
    return (int(n_rows) * int(n_bits) + 7) // 8


def dense_codes(codes: np.ndarray, n_bits: int) -> np.ndarray:
    """Row-packed codes (n_rows, ⌈P/8⌉) uint8 as the stored stream: the same matrix when P is a multiple
    of 8, else the n_rows·P bits end to end, (⌈n_rows·P/8⌉,) uint8."""
    if n_bits % 8 == 0:
        return codes
    out = np.empty(code_bytes(codes.shape[0], n_bits), dtype=np.uint8)
    step = 8 * _BLOCK_ROWS  # 8 rows of P bits end on a byte boundary, so blocks of 8k rows pack apart
    for start in range(0, codes.shape[0], step):
        block = np.unpackbits(codes[start : start + step], axis=1, count=n_bits)
        packed = np.packbits(block.ravel())
        out[start * n_bits // 8 : start * n_bits // 8 + packed.size] = packed
    return out


def row_codes(stream: np.ndarray, n_rows: int, n_bits: int) -> np.ndarray:
    """Inverse of :func:`dense_codes` for P not a multiple of 8: (n_rows, ⌈P/8⌉) uint8."""
    out = np.empty((n_rows, (n_bits + 7) // 8), dtype=np.uint8)
    step = 8 * _BLOCK_ROWS
    for start in range(0, n_rows, step):
        rows = min(step, n_rows - start)
        first = start * n_bits // 8
        bits = np.unpackbits(stream[first : first + code_bytes(rows, n_bits)], count=rows * n_bits)
        out[start : start + rows] = np.packbits(bits.reshape(rows, n_bits), axis=1)
    return out


class LSHLocalizer(_RowLocalizer):
    """Sign random projections of the map, P bits per row filling the budget, asymmetric or Hamming search.

    Parameters
    ----------
    budget : int or str, optional
        Bytes (or ``"64KB"``); P is the most bits per row that fit (module docstring).
    n_bits : int, optional
        Pin P (8 … MAX_BITS).
    scoring : {'asymmetric', 'hamming'}
        Projected query against the ±1 codes (default), or binarised query by Hamming distance.
    center : bool or 'auto'
        False (default): plain cosine. True: subtract the map mean (d float16, counted) before
        projecting (centred cosine). 'auto': for a cone, when the mean is cheap (module docstring).
    projection : {'hadamard', 'orthogonal', 'gaussian'}
        Sign flips and Walsh–Hadamard transforms (default), QR-orthonormalised Gaussian blocks, or i.i.d.
        Gaussian hyperplanes (module docstring); all regenerated from the seed, 0 bytes.
    random_state : int or None
        Seed of the projection; None draws one. The seed used is recorded (``seed_``) and saved.
    normalize, whiten, delta
        The front end (:mod:`btel.core.frontend`).
    n_jobs : int, optional
        faiss threads for the search.

    Attributes
    ----------
    n_bits_ : int
    seed_ : int
    codes_ : ndarray of shape (n_rows, ⌈n_bits_ / 8⌉), uint8
        Each row's bits, packed and zero-padded to whole bytes (stored as one dense bit stream:
        :func:`dense_codes`).
    mean_ : ndarray of shape (n_features,), float16, or None
    projection_ : object
        :func:`make_projection`'s, regenerated from ``seed_`` (not stored): ``projection_.apply(X)``
        is X R, ``projection_.matrix()`` the (n_features, n_bits_) float32 matrix R.
    n_places_, n_features_in_ : int
    row_places_ : ndarray of shape (n_rows,) or None
    fit_time_ : float

    Examples
    --------
    >>> import numpy as np
    >>> X = np.random.default_rng(0).normal(size=(100, 32)).astype(np.float32)
    >>> LSHLocalizer(budget=2000).fit(X).predict(X[:3]).tolist()
    [0, 1, 2]
    """

    label = "lsh"
    _fit_reads_row_blocks = True  # _fit_rows reads row blocks: an L2 front end hands it the map unscaled

    _parameter_constraints = {
        "n_bits": [None, Interval(int, 8, MAX_BITS)],
        "scoring": [Options("asymmetric", "hamming")],
        "center": [Options(True, False, "auto")],
        "projection": [Options(*PROJECTIONS)],
        "random_state": RANDOM_STATE,
        "n_jobs": N_JOBS,
    }

    def __init__(self, *, budget: int | str | None = None, n_bits: int | None = None, scoring: str = "asymmetric",
                 center: bool | str = False, projection: str = "hadamard", random_state: int | None = 0,
                 n_jobs: int | None = None) -> None:
        self.budget = budget
        self.n_bits = n_bits
        self.scoring = scoring
        self.center = center
        self.projection = projection
        self.random_state = random_state
        self.n_jobs = n_jobs

    def choose_bits(self, n_rows: int, n_features: int, budget: int | None, reserved: int = 0, *,
                    cone: bool = False) -> int:
        """P, the bits per row ``fit`` uses (module docstring); ``cone``: the map's rows lie in a cone."""
        mean_bytes = 2 * n_features if self._centred(n_rows, n_features, budget, reserved, cone) else 0
        if self.n_bits is not None:
            bits = int(self.n_bits)
        elif budget is None:
            bits = DEFAULT_BITS
        else:
            bits = min(self.max_bits(n_features), 8 * (budget - reserved - mean_bytes) // n_rows)
        needed = reserved + mean_bytes + code_bytes(n_rows, max(bits, 8))
        if budget is not None and (bits < 8 or needed > budget):
            minimum = reserved + mean_bytes + code_bytes(n_rows, max(bits if self.n_bits else 8, 8))
            raise_budget_too_small("LSH", budget, minimum,
                                   f"{max(bits, 8) if self.n_bits else 8}-bit codes for {n_rows} rows"
                                   + (f" + the {n_features}-value float16 mean" if mean_bytes else ""))
        return bits

    @staticmethod
    def max_bits(n_features: int) -> int:
        """The most bits per row the budget rule gives rows of ``n_features`` values."""
        return int(min(MAX_BITS, max(8, MAX_BITS_PER_DIMENSION * int(n_features))))

    def budget_saturated(self) -> bool:
        """True when the budget rule stopped at :meth:`max_bits`: a larger budget gives the same codes."""
        d = self.front_end_.n_features_out(int(self.n_features_in_))
        return self.n_bits is None and self.budget is not None and int(self.n_bits_) >= self.max_bits(d)

    def unused_budget(self) -> int:
        """Bytes of the budget left unspent because the model cannot use them (0 when not saturated)."""
        return int(budget_of(self) - self.nbytes) if self.budget_saturated() else 0

    def effective_bits(self, n_rows: int, n_features: int, budget: int | None, cone: float,
                       reserved: int = 0) -> float:
        """The entropy ``fit`` would store per map row: P bits, each worth :func:`sign_bit_entropy` when uncentred.

        Parameters
        ----------
        n_rows, n_features : int
            The map's shape after the front end.
        budget : int or None
        cone : float
            :func:`cone_ratio` of the (L2-normalised) map rows.
        reserved : int
            Bytes the front end takes from the budget.

        Returns
        -------
        float (0 when no code fits the budget)
        """
        in_cone = cone >= CENTER_CONE
        try:
            bits = self.choose_bits(n_rows, n_features, budget, reserved, cone=in_cone)
        except BudgetTooSmallError:
            return 0.0
        if self._centred(n_rows, n_features, budget, reserved, in_cone):
            return float(bits)
        return bits * sign_bit_entropy(cone)

    def _centred(self, n_rows: int, n_features: int, budget: int | None, reserved: int, cone: bool) -> bool:
        """Whether fit subtracts the mean. 'auto' plans (no map seen: ``cone`` False) as uncentred, the
        smallest plan, and centres a cone only where the mean is cheap and 8-bit codes still fit beside it."""
        if self.center != "auto":
            return bool(self.center)
        if not cone:
            return False
        return budget is None or (2 * n_features <= CENTER_SHARE * budget
                                  and reserved + 2 * n_features + code_bytes(n_rows, 8) <= budget)

    def _check_plan(self, n_rows: int, n_features_out: int, budget: int | None, reserved: int) -> None:
        self.choose_bits(n_rows, n_features_out, budget, reserved)

    def _fit_rows(self, X: np.ndarray, budget: int | None, reserved: int) -> None:
        n_rows, d = X.shape
        moments = mean_and_rms(X)  # row blocks: a lazily scaled map is scaled as it is read
        mean, cone = moments[0], cone_ratio(X, moments) >= CENTER_CONE
        bits = self.choose_bits(n_rows, d, budget, reserved, cone=cone)
        seed = int(self.random_state) if self.random_state is not None else \
            int(np.random.default_rng().integers(0, 2**31 - 1))
        self.n_bits_, self.seed_ = bits, seed
        self.mean_ = mean.astype(np.float16) if self._centred(n_rows, d, budget, reserved, cone) else None
        self.projection_ = make_projection(d, bits, seed, self.projection)
        codes = np.empty((n_rows, (bits + 7) // 8), dtype=np.uint8)
        step = max(1, BLOCK_VALUES // max(bits, d))
        for start in range(0, n_rows, step):
            codes[start : start + step] = np.packbits(self._project(X[start : start + step]) > 0, axis=1)
        self.codes_ = codes
        self._stored_codes = None
        self._prepare()

    def _project(self, X: np.ndarray) -> np.ndarray:
        Z = np.asarray(X, dtype=np.float32)
        if self.mean_ is not None:
            Z = Z - self.mean_.astype(np.float32)
        return self.projection_.apply(Z)

    def _prepare(self) -> None:
        """Runtime state (never stored): the lookup-table scanner of asymmetric scoring."""
        self._index = self._build_index()

    def _build_index(self) -> Any:
        """Asymmetric scoring: the lookup-table scanner of the codes (:func:`signscan.byte_tables`)."""
        return None if self.scoring == "hamming" else signscan.byte_tables(self.codes_.shape[1])

    def _search_rows(self, Q: np.ndarray, k: int, scores: bool = True) -> tuple[np.ndarray, np.ndarray]:
        P = self._project(Q)
        if self.scoring == "hamming":  # zero padding bits add nothing to a Hamming distance
            dist, rows = faiss.knn_hamming(np.packbits(P > 0, axis=1), self.codes_, k)
            return -dist.astype(np.float64), rows
        return signscan.search(self._index, self.codes_, P, k)

    def _place_scores(self, Q: np.ndarray) -> np.ndarray:
        """Every row's asymmetric score, block by block (places = rows); otherwise from the search."""
        if self.scoring == "hamming" or self.row_places_ is not None:
            return super()._place_scores(Q)
        check_magnitude(Q, "Q")
        return signscan.scores(self.codes_, self._project(Q))

    def summary(self) -> str:
        """One line: bits per row, scoring, seed, the bytes against the budget and the front end."""
        centred = "centred" if self.mean_ is not None else "uncentred"
        unused = self.unused_budget()
        cap = (f"; budget saturated at {MAX_BITS_PER_DIMENSION}·d bits per row, {unused} B unused"
               if unused else "")
        return (f"lsh: {self.n_bits_} bits per row, {self.scoring} scoring, {self.projection} projection "
                f"from seed {self.seed_} (0 B), {centred}; {spent_text(self)}; front end "
                f"{self.front_end_.describe()}{cap}")

    def _model_arrays(self) -> dict[str, np.ndarray]:
        if getattr(self, "_stored_codes", None) is None:  # built once, when asked: nbytes asks for it often
            self._stored_codes = dense_codes(self.codes_, int(self.n_bits_))
        codes = self._stored_codes
        return {"codes": codes} if self.mean_ is None else {"codes": codes, "mean": self.mean_}

    def _model_state(self) -> dict[str, Any]:
        return {"n_bits": int(self.n_bits_), "seed": int(self.seed_), "projection": self.projection,
                "n_rows": int(self.codes_.shape[0])}

    def _model_specs(self, state: dict[str, Any], d: int) -> dict[str, ArraySpec]:
        bits = read_state_int(state, "n_bits", 8, MAX_BITS)
        read_state_int(state, "seed", 0, 2**63 - 1)
        recorded_kind(state, "projection", PROJECTIONS, "LSH")
        # Files before the dense stream record no n_rows (their P is a multiple of 8).
        n_rows = read_state_int(state, "n_rows", 1, 2**40) if "n_rows" in state or bits % 8 else None
        if bits % 8 == 0:  # the byte matrix, as every file before the dense stream
            codes = ArraySpec((n_rows, bits // 8), np.uint8)
        else:
            codes = ArraySpec((code_bytes(n_rows, bits),), np.uint8)
        return {"codes": codes, "mean": ArraySpec((d,), np.float16, required=self.center is True)}

    def _n_rows(self) -> int:
        return int(self.codes_.shape[0])

    def _restore_model(self, arrays: dict[str, np.ndarray], state: dict[str, Any]) -> None:
        check_model_values(arrays, ("mean",), "LSH")
        if self.center is False and "mean" in arrays:
            raise ModelFileError("the LSH model file holds a mean but its parameters say center=False.")
        self.n_bits_, self.seed_ = int(state["n_bits"]), int(state["seed"])
        stored = np.ascontiguousarray(arrays["codes"])  # shape checked against the state (_model_specs)
        # The row matrix is what the search reads; a dense stream is rebuilt only when saved (or measured).
        self.codes_ = stored if stored.ndim == 2 else row_codes(stored, int(state["n_rows"]), self.n_bits_)
        self._stored_codes = stored if stored.ndim == 2 else None
        self.mean_ = arrays.get("mean")
        # The projection the codes were made with: files that record none used the Gaussian one.
        self.projection = recorded_kind(state, "projection", PROJECTIONS, "LSH", self.projection)
        self.projection_ = make_projection(self.front_end_.n_features_out(int(state["n_features_in"])),
                                           self.n_bits_, self.seed_, self.projection)
        self._prepare()

    def __getstate__(self) -> dict[str, Any]:
        state = super().__getstate__()
        state.pop("_stored_codes", None)
        return state
