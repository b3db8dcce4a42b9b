"""Seeded sign random projections (locality-sensitive hashing, Charikar 2002) filling the byte budget.

Fit: draw a d×P projection R from the recorded seed, store the P signs of ``x_i R`` of every
(front-end transformed) map row, packed 8 to a byte. Nothing else is stored: R is regenerated from
the seed at fit and at load (the storage rule: anything regenerated from a recorded seed costs 0
bytes, as btel-codes' codewords), so the model is the codes plus, with ``center=True``, the map
mean at float16.

Scoring (``scoring``):

- ``'asymmetric'`` (default): the query is projected but not binarised,
  score_i = (qR) · sign(x_i R) — the inner product of the projected query with the ±1 code of row i
  (Gordo et al. 2014; the query's own quantisation error is avoided). The ±1 codes are unpacked
  once into a float32 runtime cache (N·P·4 bytes of memory, never stored) when that is at most
  :data:`CACHE_VALUES` values; otherwise they are unpacked block by block at each search.
- ``'hamming'``: the query is binarised too and the map is searched by Hamming distance (faiss
  ``IndexBinaryFlat``, an exact popcount scan); score = −distance.

Projection (``projection``): ``'orthogonal'`` (default) — the seed's Gaussian d×P matrix with every
block of d consecutive columns orthonormalised (QR, signs fixed so the block is Haar-distributed) and
scaled by √d: within a block the hyperplanes are exactly orthogonal, which lowers the variance of the
angle the P signs estimate (super-bit LSH, Ji et al. 2012) at the same bytes. ``'gaussian'``: the
Gaussian matrix itself, i.i.d. hyperplanes (model files that record no projection were written with
it). Measured, mean of 5 seeds, asymmetric scoring (``benchmarks/bench_lsh_projection.py`` on
``btel experiment frontier``'s maps), orthogonal against Gaussian: synthetic independent places
16 KB (128 bits, d = 256) R@1 0.749 vs 0.669, synthetic route 64 KB (250 bits) R@2 0.972 vs 0.879,
Gardens Point 4 KB 0.429 vs 0.416, Nordland 256 KB 0.258 / 0.248 vs 0.252 / 0.234; within
−0.006 … +0.016 of each other in the other cells (Gardens Point at 8192 bits, 17 blocks: 0.487 vs
0.485). The QR costs about 2·d·P² flops at fit and at load (0.15 s at d = 3780,
P = 552; 1.9 s at P = 2216; 6 s at d = P = 4096, on one thread): pass ``projection='gaussian'``
where load time matters more than the last hundredths of recall.

Budget rule: P = ⌊8·(budget − reserved − mean bytes) / n_rows⌋ bits per row (every bit the budget
holds; at least 8), at most :data:`MAX_BITS`; without a budget P = :data:`DEFAULT_BITS`. ``n_bits``
pins P. The codes are stored as one stream of n_rows·P bits (⌈n_rows·P/8⌉ bytes): when P is a
multiple of 8 that is the (n_rows, P/8) byte matrix of earlier files, otherwise a flat byte array
(and the state records n_rows). Rows were once rounded down to whole bytes, which left up to 7 bits
per row of the budget unspent: 48 instead of 53 bits for 600 places at 4 KB.

``center=True`` subtracts the map mean (d float16, counted) before the projection, so the
hyperplanes cut through the data rather than past it. ``center='auto'`` (default) does so when the
map's rows lie in a cone — ‖mean row‖ ≥ :data:`CENTER_CONE` (0.5) × their RMS length, i.e. a mean
cosine between unit rows of at least 0.25, where a hyperplane through the origin leaves most rows
on one side and its bit says little — and the mean costs at most :data:`CENTER_SHARE` (1/8) of the
budget (always without a budget), so that at 1 KB the bits are not spent on a mean. Measured
(``python benchmarks/bench_lsh_center.py``, three seeds, centred − uncentred, forced): Nordland HOG
(‖mean‖ 0.75) +0.026 … +0.034 at 64 KB and +0.09 … +0.10 at 256 KB; Gardens Point NetVLAD (0.17)
−0.018 / −0.032 at 64 / 256 KB, permuted −0.005 … −0.013; the 256-D synthetic maps (0.25)
−0.022 … +0.018. Before, 'auto' centred on the cost condition alone.

Effective bits (:meth:`LSHLocalizer.effective_bits`, what :mod:`btel.methods.auto` asks before it
chooses LSH): a sign bit that is the same for most rows carries less than one bit. For unit rows in
a cone of ratio c (:func:`cone_ratio`) cut by a random hyperplane through the origin, the mean's
projection is N(0, c²/d) and a row's own part N(0, (1 − c²)/d), so the share of rows on the
minority side is Φ(−|z|·c/√(1 − c²)), z ~ N(0, 1); :func:`sign_bit_entropy` is its expected binary
entropy (1 at c = 0, 0.88 at 0.5, 0.68 at 0.75, 0.32 at 0.95). Centred codes count their P bits
whole. On Nordland HOG at 16 KB (P = 36, c = 0.75, uncentred) that is 24 effective bits; the
per-bit entropies measured on the map's own codes gave 25.0 / 25.6.
"""

from __future__ import annotations

from typing import Any

import faiss
import numpy as np

from ..._validation import N_JOBS, RANDOM_STATE, Budget, Interval, Options, read_state_int
from ...base import ArraySpec
from ...exceptions import BudgetTooSmallError, InvalidParameterError, ModelFileError
from ._common import _RowLocalizer, check_model_values, raise_budget_too_small

__all__ = ["LSHLocalizer", "projection_matrix", "PROJECTIONS", "code_bytes", "dense_codes", "row_codes",
           "cone_ratio", "sign_bit_entropy"]

#: Without a budget, codes have this many bits.
DEFAULT_BITS = 256
#: Most bits per row the budget rule gives (beyond this, asymmetric LSH is within noise of cosine).
MAX_BITS = 8192
#: ``center='auto'`` centres when the float16 mean costs at most this share of the budget ...
CENTER_SHARE = 1 / 8
#: ... and the map's rows lie in a cone: ‖mean row‖ at least this × their RMS length (module docstring).
CENTER_CONE = 0.5
#: The ±1 codes are cached as float32 when N·P is at most this (256 MB).
CACHE_VALUES = 1 << 26
#: Map rows unpacked at a time when the codes are not cached.
_BLOCK_ROWS = 4096


#: The projections ``projection`` takes (module docstring); files without one used the last.
PROJECTIONS = ("orthogonal", "gaussian")


def projection_matrix(n_features: int, n_bits: int, seed: int, kind: str = "gaussian") -> np.ndarray:
    """The d×P projection of a seed, float32: Gaussian (numpy's PCG64 ``standard_normal``), or that matrix
    with each block of d consecutive columns orthonormalised and scaled by √d (``kind='orthogonal'``).

    Deterministic for a given numpy bit generator, so it is regenerated rather than stored (the
    orthogonal one up to the last bits of the platform's QR, which move a query's projection, not
    the stored signs).
    """
    rng = np.random.default_rng(int(seed))
    gaussian = rng.standard_normal((int(n_features), int(n_bits)), dtype=np.float32)
    if kind == "gaussian":
        return gaussian
    if kind != "orthogonal":
        raise InvalidParameterError(f"projection must be one of {PROJECTIONS}; got {kind!r}.")
    d = int(n_features)
    out = np.empty_like(gaussian)
    for start in range(0, gaussian.shape[1], d):
        q, r = np.linalg.qr(gaussian[:, start : start + d].astype(np.float64))
        # Sign-fixed Q is Haar-distributed; √d gives its columns the Gaussian columns' typical length.
        out[:, start : start + d] = q * (np.sign(np.diag(r)) * np.sqrt(d))
    return out


def cone_ratio(X: np.ndarray, mean: np.ndarray | None = None) -> float:
    """‖mean row‖ / RMS row length of ``X`` (n_rows, d): 0 for rows spread around the origin, 1 when all are equal.

    For unit rows its square is the mean cosine between rows (self-pairs included).
    """
    mean = X.mean(axis=0, dtype=np.float64) if mean is None else mean
    rms = np.sqrt(np.einsum("ij,ij->", X, X, dtype=np.float64) / max(X.shape[0], 1))
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
        Subtract the map mean (stored as d float16 values, counted) before projecting; 'auto': when
        the rows lie in a cone (‖mean‖ ≥ 0.5 × RMS length) and the mean costs at most 1/8 of the budget.
    projection : {'orthogonal', 'gaussian'}
        Orthonormalised blocks of d hyperplanes (default) or i.i.d. Gaussian ones (module docstring);
        both regenerated from the seed, 0 bytes.
    random_state : int or None
        Seed of the projection; None draws one. The seed used is recorded (``seed_``) and saved.
    normalize, whiten, delta
        The front end (:mod:`btel.frontend`).
    n_jobs : int, optional
        faiss threads for the Hamming search.

    Attributes
    ----------
    n_bits_ : int
    seed_ : int
    codes_ : ndarray of shape (n_rows, ⌈n_bits_ / 8⌉), uint8
        Each row's bits, packed and zero-padded to whole bytes (stored as one dense bit stream:
        :func:`dense_codes`).
    mean_ : ndarray of shape (n_features,), float16, or None
    projection_ : ndarray of shape (n_features, n_bits_), float32
        Regenerated from ``seed_`` (not stored).
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

    _parameter_constraints = {
        "budget": [Budget()],
        "n_bits": [None, Interval(int, 8, MAX_BITS)],
        "scoring": [Options("asymmetric", "hamming")],
        "center": [Options(True, False, "auto")],
        "projection": [Options(*PROJECTIONS)],
        "random_state": RANDOM_STATE,
        "n_jobs": N_JOBS,
    }

    def __init__(self, *, budget: int | str | None = None, n_bits: int | None = None, scoring: str = "asymmetric",
                 center: bool | str = "auto", projection: str = "orthogonal", random_state: int | None = 0,
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
            bits = min(MAX_BITS, 8 * (budget - reserved - mean_bytes) // n_rows)
        needed = reserved + mean_bytes + code_bytes(n_rows, max(bits, 8))
        if budget is not None and (bits < 8 or needed > budget):
            minimum = reserved + mean_bytes + code_bytes(n_rows, max(bits if self.n_bits else 8, 8))
            raise_budget_too_small("LSH", budget, minimum,
                                   f"{max(bits, 8) if self.n_bits else 8}-bit codes for {n_rows} rows"
                                   + (f" + the {n_features}-value float16 mean" if mean_bytes else ""))
        return bits

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
        float
            0 when no code fits the budget.
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
        mean = X.mean(axis=0, dtype=np.float64)
        cone = cone_ratio(X, mean) >= CENTER_CONE
        bits = self.choose_bits(n_rows, d, budget, reserved, cone=cone)
        seed = int(self.random_state) if self.random_state is not None else \
            int(np.random.default_rng().integers(0, 2**31 - 1))
        self.n_bits_, self.seed_ = bits, seed
        self.mean_ = mean.astype(np.float16) if self._centred(n_rows, d, budget, reserved, cone) else None
        self.projection_ = projection_matrix(d, bits, seed, self.projection)
        codes = np.empty((n_rows, (bits + 7) // 8), dtype=np.uint8)
        for start in range(0, n_rows, _BLOCK_ROWS):
            codes[start : start + _BLOCK_ROWS] = np.packbits(self._project(X[start : start + _BLOCK_ROWS]) > 0, axis=1)
        self.codes_ = codes
        self._stored_codes = None
        self._prepare()

    def _project(self, X: np.ndarray) -> np.ndarray:
        Z = np.asarray(X, dtype=np.float32)
        if self.mean_ is not None:
            Z = Z - self.mean_.astype(np.float32)
        return Z @ self.projection_

    def _prepare(self) -> None:
        """Runtime caches (never stored): the faiss binary index or the ±1 codes as float32."""
        self._index = self._build_index()

    def _build_index(self) -> Any:
        self._signs = None
        if self.scoring == "hamming":  # zero padding bits add nothing to a Hamming distance
            index = faiss.IndexBinaryFlat(8 * self.codes_.shape[1])
            index.add(np.ascontiguousarray(self.codes_))
            return index
        if self.codes_.shape[0] * int(self.n_bits_) <= CACHE_VALUES:
            self._signs = self._unpack(self.codes_)
        return None

    def _unpack(self, codes: np.ndarray) -> np.ndarray:
        bits = np.unpackbits(codes, axis=1, count=int(self.n_bits_)).astype(np.float32)
        return bits * 2.0 - 1.0

    def _search_rows(self, Q: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
        from ...base import top_k

        if self.scoring == "hamming":
            dist, rows = self._index.search(np.packbits(self._project(Q) > 0, axis=1), k)
            return -dist.astype(np.float64), rows.astype(np.int64)
        P = self._project(Q)
        if self._signs is not None:
            return top_k(P @ self._signs.T, k)
        n_rows = self.codes_.shape[0]
        scores = np.empty((Q.shape[0], n_rows), dtype=np.float32)
        for start in range(0, n_rows, _BLOCK_ROWS):
            scores[:, start : start + _BLOCK_ROWS] = P @ self._unpack(self.codes_[start : start + _BLOCK_ROWS]).T
        return top_k(scores, k)

    def summary(self) -> str:
        """One line: bits per row, scoring, seed and the front end."""
        return (f"lsh: {self.n_bits_} bits per row, {self.scoring} scoring, projection from seed {self.seed_} "
                f"(0 B), {'centred' if self.mean_ is not None else 'uncentred'}; front end "
                f"{self.front_end_.describe()}")

    def _model_arrays(self) -> dict[str, np.ndarray]:
        if getattr(self, "_stored_codes", None) is None:  # built once: nbytes asks for it often
            self._stored_codes = dense_codes(self.codes_, int(self.n_bits_))
        codes = self._stored_codes
        return {"codes": codes} if self.mean_ is None else {"codes": codes, "mean": self.mean_}

    def _model_state(self) -> dict[str, Any]:
        return {"n_bits": int(self.n_bits_), "seed": int(self.seed_), "projection": self.projection,
                "n_rows": int(self.codes_.shape[0])}

    def _model_specs(self, state: dict[str, Any], d: int) -> dict[str, ArraySpec]:
        bits = read_state_int(state, "n_bits", 8, MAX_BITS)
        read_state_int(state, "seed", 0, 2**63 - 1)
        kind = state.get("projection", PROJECTIONS[-1])
        if kind not in PROJECTIONS:
            raise ModelFileError(f"the LSH model file's projection {str(kind)[:40]!r} is not one of {PROJECTIONS}.")
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
        self.codes_ = stored if stored.ndim == 2 else row_codes(stored, int(state["n_rows"]), self.n_bits_)
        self._stored_codes = stored
        self.mean_ = arrays.get("mean")
        # The projection the codes were made with: files that record none used the Gaussian one.
        if "projection" in state and state["projection"] != self.projection:
            raise ModelFileError(f"the LSH model file's projection {state['projection']!r} contradicts its "
                                 f"parameters ({self.projection!r}).")
        self.projection = state.get("projection", PROJECTIONS[-1])
        self.projection_ = projection_matrix(self.front_end_.n_features_out(int(state["n_features_in"])),
                                             self.n_bits_, self.seed_, self.projection)
        self._prepare()

    def __getstate__(self) -> dict[str, Any]:
        state = super().__getstate__()
        state.pop("_signs", None)
        state.pop("_stored_codes", None)
        return state
