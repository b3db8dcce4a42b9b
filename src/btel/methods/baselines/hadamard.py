"""A seeded structured orthogonal projection: random sign flips and fast Walsh–Hadamard transforms.

A row x ∈ R^d is zero-padded to D = 2^⌈log2 d⌉ and mapped, for each block b of D outputs, to

    y_b = H S_{b,3} H S_{b,2} H S_{b,1} x,

H the orthonormal Sylvester–Hadamard matrix (H Hᵀ = I) and S_{b,r} diagonal matrices of seeded
random signs: three rounds, as the structured orthogonal random features of Yu et al. (2016) and
FALCONN's cross-polytope LSH (Andoni et al. 2015). Each block is an exactly orthogonal D × D
transform (its D hyperplanes are orthogonal in the padded space), blocks are independent, and the
projection is the first P outputs of the blocks end to end. Nothing d × d is formed, nothing is
factorised, and the signs (3 × D per block) are all that is drawn from the seed.

H_D is applied as the Kronecker product of Hadamard matrices of at most :data:`MAX_FACTOR` rows, one
stack of small matrix products per factor: per row and round about D · Σ factors multiply-adds in
BLAS, instead of d · P for a dense projection. Where d · P is at most
:data:`DENSE_VALUES` the d × P matrix is formed once (min(d, P) transforms of unit vectors) and used
instead: a small product beats the transform's fixed cost for one query, and its 3·D·Σ factors work
per row when P ≪ D.
"""

from __future__ import annotations

import functools

import numpy as np

__all__ = ["SignedHadamard", "HadamardRotation", "DenseTransform", "fwht", "ROUNDS", "MAX_FACTOR",
           "DENSE_VALUES"]

#: Sign-flip + Hadamard rounds per block.
ROUNDS = 3
#: Largest Hadamard factor applied as one matrix product.
MAX_FACTOR = 64
#: The d × P matrix is formed (a runtime cache, never stored) when it has at most this many values (4 MB).
DENSE_VALUES = 1 << 20
#: Values of the (rows × blocks × D) work buffer transformed at a time (4 MB of float32).
_WORK_VALUES = 1 << 20


@functools.lru_cache(maxsize=16)
def _factor(f: int) -> np.ndarray:
    """The orthonormal Sylvester–Hadamard matrix of order f (a power of two), H_2^{⊗k} / √f, float32."""
    H = np.ones((1, 1))
    while H.shape[0] < f:  # numpy only: scipy.linalg.hadamard would add scipy.linalg to every model load
        H = np.kron(H, [[1.0, 1.0], [1.0, -1.0]])
    return (H / np.sqrt(f)).astype(np.float32)


def _factors(D: int) -> list[int]:
    """Powers of two of about equal size, each at most MAX_FACTOR, whose product is D."""
    k, top = D.bit_length() - 1, MAX_FACTOR.bit_length() - 1
    m = max(1, -(-k // top))
    return [1 << (k // m + (i < k % m)) for i in range(m)]


def fwht(X: np.ndarray) -> np.ndarray:
    """The orthonormal Walsh–Hadamard transform of every row, X Hᵀ = X H (Sylvester order).

    Parameters
    ----------
    X : ndarray of shape (n, D), float32
        D a power of two.

    Returns
    -------
    ndarray of shape (n, D), float32
    """
    n, D = X.shape
    if D & (D - 1):
        raise ValueError(f"the Walsh–Hadamard transform needs a power-of-two width; got {D}.")
    Y = np.asarray(X, dtype=np.float32)
    # H_D = H_f1 ⊗ … ⊗ H_fm: in the (n, f1, …, fm) view, each factor multiplies its own axis — a stack of
    # small products (f_i × f_i by f_i × the later axes), the last one plain rows times H_fm.
    before = 1
    for f in _factors(D):
        rest = D // (before * f)
        Y = Y.reshape(-1, f) @ _factor(f) if rest == 1 else np.matmul(_factor(f), Y.reshape(-1, f, rest))
        before *= f
    return Y.reshape(n, D)


def _random_signs(seed: int, shape: tuple[int, ...]) -> np.ndarray:
    """±1 float32 signs of a seed (numpy's PCG64 ``integers``): the only thing a transform draws."""
    rng = np.random.default_rng(int(seed))
    return (rng.integers(0, 2, size=shape, dtype=np.int8) * 2 - 1).astype(np.float32)


class _SeededTransform:
    """What the two seeded transforms share: ``apply`` (X M, by a small cached M or the transform
    itself), ``matrix()`` and the run-time ``nbytes``. A subclass sets ``n_features``, ``n_outputs``
    and ``signs``, and defines ``_transform(X)`` and ``_matrix()``."""

    kind = "hadamard"
    n_features: int
    n_outputs: int
    signs: np.ndarray
    _dense: np.ndarray | None = None

    def _cache_small_matrix(self) -> None:
        # A small product beats the transform's fixed cost for one query.
        if self.n_features * self.n_outputs <= DENSE_VALUES:
            self._dense = self._matrix()

    @property
    def nbytes(self) -> int:
        """Bytes held at run time (signs and the small dense matrix); none of it is stored."""
        return int(self.signs.nbytes + (0 if self._dense is None else self._dense.nbytes))

    def apply(self, X: np.ndarray) -> np.ndarray:
        """The transform of every row.

        Parameters
        ----------
        X : ndarray of shape (n, n_features), float32

        Returns
        -------
        ndarray of shape (n, n_outputs), float32
        """
        X = np.asarray(X, dtype=np.float32)
        if self._dense is not None:
            return X @ self._dense
        return self._transform(X)

    def matrix(self) -> np.ndarray:
        """The transform as an (n_features, n_outputs) float32 matrix M: :meth:`apply` is ``X @ M``."""
        return self._matrix() if self._dense is None else self._dense.copy()

    def _transform(self, X: np.ndarray) -> np.ndarray:
        raise NotImplementedError

    def _matrix(self) -> np.ndarray:
        raise NotImplementedError


class DenseTransform:
    """A d × P matrix held whole, with the seeded transforms' interface (``apply``, ``matrix()``,
    ``nbytes``): ``lsh``'s ``'orthogonal'`` and ``'gaussian'`` projections, ``rabitq``'s ``'qr'`` rotation."""

    def __init__(self, matrix: np.ndarray, kind: str) -> None:
        self._matrix, self.kind = matrix, kind
        self.n_features, self.n_outputs = (int(v) for v in matrix.shape)

    @property
    def nbytes(self) -> int:
        return int(self._matrix.nbytes)

    def apply(self, X: np.ndarray) -> np.ndarray:
        return np.asarray(X, dtype=np.float32) @ self._matrix

    def matrix(self) -> np.ndarray:
        return self._matrix


class SignedHadamard(_SeededTransform):
    """The seeded projection of the module docstring, d features to P outputs.

    Parameters
    ----------
    n_features : int
        d.
    n_outputs : int
        P.
    seed : int
        Seed of the signs (numpy's PCG64, ``integers``).

    Attributes
    ----------
    width : int
        D, d padded to a power of two.
    signs : ndarray of shape (n_blocks, ROUNDS, D), float32
        ±1.
    """

    def __init__(self, n_features: int, n_outputs: int, seed: int) -> None:
        self.n_features, self.n_outputs = int(n_features), int(n_outputs)
        self.width = 1 << max(int(n_features) - 1, 1).bit_length()
        n_blocks = -(-self.n_outputs // self.width)
        self.signs = _random_signs(seed, (n_blocks, ROUNDS, self.width))
        self._cache_small_matrix()

    def _matrix(self) -> np.ndarray:
        """R from min(d, P) transforms: the rows of the identity forward, or P unit vectors through the
        transposed rounds (column j of block b is S_1 H S_2 H S_3 H e_j, row form)."""
        d, D = self.n_features, self.width
        if d <= self.n_outputs:
            return self._transform(np.eye(d, dtype=np.float32))
        out = np.empty((d, self.n_outputs), dtype=np.float32)
        for block in range(self.signs.shape[0]):
            count = min(D, self.n_outputs - block * D)
            work = np.eye(count, D, dtype=np.float32)
            for r in reversed(range(ROUNDS)):
                work = fwht(work)
                work *= self.signs[block, r]
            out[:, block * D : block * D + count] = work[:, :d].T
        return out

    def _transform(self, X: np.ndarray) -> np.ndarray:
        n, d = X.shape
        n_blocks, D = self.signs.shape[0], self.width
        out = np.empty((n, self.n_outputs), dtype=np.float32)
        step = max(1, _WORK_VALUES // (n_blocks * D))
        for start in range(0, n, step):
            rows = X[start : start + step]
            work = np.zeros((rows.shape[0], n_blocks, D), dtype=np.float32)
            work[:, :, :d] = rows[:, None, :]
            for r in range(ROUNDS):
                work *= self.signs[:, r]
                work = fwht(work.reshape(-1, D)).reshape(rows.shape[0], n_blocks, D)
            out[start : start + rows.shape[0]] = work.reshape(rows.shape[0], -1)[:, : self.n_outputs]
        return out


class HadamardRotation(_SeededTransform):
    """A seeded orthogonal rotation of R^d (any d, no padding), keeping its first D coordinates.

    With k the largest power of two ≤ d, each of :data:`ROUNDS` rounds flips the signs of all d
    coordinates and applies the orthonormal Walsh–Hadamard transform to the first k; when k < d it
    then flips the signs again, transforms the last k, and mixes the two halves with a butterfly
    ((x_i, x_{i+h}) ↦ ((x_i + x_{i+h}) / √2, (x_i − x_{i+h}) / √2), h = ⌊d/2⌋), so that the
    coordinates the two blocks do not share still mix. Every step is an orthogonal map of R^d, so
    the product R is exactly orthogonal: no padding, no d × d matrix, no factorisation, and
    O(d log d) work per row — the family of the RaBitQ authors' library's default rotator (which
    pads d and runs four rounds), in place of a QR of a Gaussian matrix (measured against it:
    ``docs/decisions/rabitq.md``). The
    first D rows of R are orthonormal, so ``apply`` projects on a random D-dimensional subspace.

    Parameters
    ----------
    n_features : int
        d.
    n_outputs : int
        D ≤ d, the coordinates kept.
    seed : int
        Seed of the signs (numpy's PCG64, ``integers``).

    Attributes
    ----------
    signs : ndarray of shape (ROUNDS, 2, d), float32
        ±1: before the first and before the last transform of each round.
    """

    def __init__(self, n_features: int, n_outputs: int, seed: int) -> None:
        self.n_features, self.n_outputs = int(n_features), int(n_outputs)
        if not 1 <= self.n_outputs <= self.n_features:
            raise ValueError(f"a rotation keeps 1 … d = {self.n_features} coordinates; got {self.n_outputs}.")
        self.width = 1 << (self.n_features.bit_length() - 1)
        self.signs = _random_signs(seed, (ROUNDS, 2, self.n_features))
        self._cache_small_matrix()

    def _transform(self, X: np.ndarray) -> np.ndarray:
        """The first D coordinates of every rotated row, in blocks of rows."""
        n, d = X.shape
        out = np.empty((n, self.n_outputs), dtype=np.float32)
        step = max(1, _WORK_VALUES // d)
        for start in range(0, n, step):
            out[start : start + step] = self._steps(X[start : start + step], forward=True)[:, : self.n_outputs]
        return out

    def _matrix(self) -> np.ndarray:
        """The d × D matrix M (Mᵀ M = I), from D unit vectors through the transposed steps in reverse
        order (each step is symmetric): D · d log d work, never d × d."""
        return np.ascontiguousarray(self._steps(np.eye(self.n_outputs, self.n_features, dtype=np.float32),
                                                forward=False).T)

    def _steps(self, rows: np.ndarray, forward: bool) -> np.ndarray:
        """R applied to each row (forward: x ↦ R x) or Rᵀ: every step is symmetric, so Rᵀ is the same
        steps in reverse order."""
        d, k, h = self.n_features, self.width, self.n_features // 2
        work = np.array(rows, dtype=np.float32, copy=True)
        steps = [(r, step) for r in range(ROUNDS) for step in (("first",) if k == d else ("first", "last", "mix"))]
        for r, step in (steps if forward else reversed(steps)):
            if step == "mix":
                a, b = work[:, :h].copy(), work[:, h : 2 * h]
                work[:, :h] += b
                work[:, h : 2 * h] = a - b
                work[:, : 2 * h] *= np.float32(np.sqrt(0.5))
                continue
            signs = self.signs[r, 0 if step == "first" else 1]
            part = slice(0, k) if step == "first" else slice(d - k, d)
            if forward:
                work *= signs
            work[:, part] = fwht(work[:, part])
            if not forward:
                work *= signs
        return work
