"""Shrinkage whitening (``whiten="shrink"``): x ↦ (Σ + λI)^(-1/2)(x − μ), then L2, low-rank and counted.

Σ is the covariance of the (normalised) map rows, μ their mean. The rule, fixed in advance and the same
for every method and map:

- λ = :data:`SHRINK_LAMBDA` (1.0) × the mean eigenvalue of Σ (its trace / d);
- rank r: the top r eigenvalues s_1 ≥ … ≥ s_r of Σ are shrunk exactly; every other eigenvalue is
  taken to equal s_{r+1} (a partial whitening: the r dominant directions are flattened down to the
  level of the next one, the rest of the space is scaled uniformly). r is the largest rank whose
  stored arrays fit in :data:`SHRINK_BUDGET_SHARE` (a quarter) of the model's budget, at most
  :data:`SHRINK_MAX_RANK` (32) and at most min(d, n_rows − 2); without a budget r is that cap.
  With r = 0 the transform is centring only.

Why these choices (the figures and the study commands): ``docs/decisions/whitening.md``.

Because the result is L2-normalised, a global scale does not matter and the transform is stored as

    y ∝ z + U (g ⊙ (Uᵀ z)),   z = x − μ,   g_j = sqrt((ρ + λ) / (s_j + λ)) − 1,

with U the d×r eigenvectors. Stored (all counted by the storage rule): μ as d float16 values,
U at 4 bits per entry (levels −7 … 7, two to a byte, one float32 scale per column), g as r float32
values — 2d + r·(⌈d/2⌉ + 8) bytes.
The 4-bit basis scores level with int8 at half the bytes; model files written with the int8 basis
(``frontend_shrink_basis``) load and answer as before.
"""

from __future__ import annotations

import numpy as np

__all__ = ["SHRINK_LAMBDA", "SHRINK_BUDGET_SHARE", "SHRINK_MAX_RANK", "SHRINK_BASIS_BITS", "shrink_rank",
           "shrink_bytes", "fit_shrink", "apply_shrink", "pack_basis", "unpack_basis"]

#: λ as a fraction of the mean eigenvalue of the map covariance.
SHRINK_LAMBDA = 1.0
#: At most this share of a model's budget goes to the whitening arrays.
SHRINK_BUDGET_SHARE = 0.25
#: Most eigenvectors kept.
SHRINK_MAX_RANK = 32
#: Wide maps of more values than this take their top directions from the rows' Gram matrix.
GRAM_VALUES = 1 << 20


#: Bits per entry of the stored basis (levels −(2^(b−1) − 1) … 2^(b−1) − 1).
SHRINK_BASIS_BITS = 4
_LEVELS = 2 ** (SHRINK_BASIS_BITS - 1) - 1


def shrink_bytes(n_features: int, rank: int) -> int:
    """Stored bytes of a rank-r shrinkage whitening of d features: 2d + r(⌈d/2⌉ + 8)."""
    return 2 * int(n_features) + int(rank) * ((int(n_features) + 1) // 2 + 8)


def pack_basis(basis: np.ndarray) -> np.ndarray:
    """The (d, r) int8 basis levels in [−7, 7] as (r, ⌈d/2⌉) uint8, two 4-bit entries a byte.

    Entry i of column j is nibble i % 2 (low first) of byte i // 2 of row j, stored as level + 8.
    """
    d, r = basis.shape
    if basis.size and int(np.abs(basis).max()) > _LEVELS:
        raise ValueError(f"basis levels exceed ±{_LEVELS}: not a {SHRINK_BASIS_BITS}-bit basis.")
    nibbles = np.full((r, 2 * ((d + 1) // 2)), 8, dtype=np.uint8)
    nibbles[:, :d] = (basis.T.astype(np.int16) + 8).astype(np.uint8)
    return np.ascontiguousarray(nibbles[:, 0::2] | (nibbles[:, 1::2] << 4))


def unpack_basis(packed: np.ndarray, n_features: int) -> np.ndarray:
    """Inverse of :func:`pack_basis`: (r, ⌈d/2⌉) uint8 → (d, r) int8 levels in [−8, 7]."""
    r = packed.shape[0]
    nibbles = np.empty((r, 2 * packed.shape[1]), dtype=np.int8)
    nibbles[:, 0::2] = packed & 15
    nibbles[:, 1::2] = packed >> 4
    return np.ascontiguousarray((nibbles[:, : int(n_features)] - 8).T)


def shrink_rank(n_features: int, n_rows: int | None, budget: int | None) -> int:
    """The rank r the rule gives (module docstring)."""
    cap = min(SHRINK_MAX_RANK, int(n_features))
    if n_rows is not None:
        cap = min(cap, max(int(n_rows) - 2, 0))
    if budget is None:
        return cap
    share = int(SHRINK_BUDGET_SHARE * budget) - 2 * int(n_features)
    return int(max(0, min(cap, share // ((int(n_features) + 1) // 2 + 8))))


def fit_shrink(Z: np.ndarray, rank: int,
               levels: int = _LEVELS) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Learn the stored arrays from the map rows ``Z`` (n, d) float32.

    Raises :class:`~btel.exceptions.InvalidDescriptorsError` when a column mean exceeds float16's range.

    ``levels``: the basis is quantised per column to the integers −levels … levels (7: the 4-bit
    basis btel stores; 127 gives the int8 basis of earlier files, for comparison).

    Returns
    -------
    mean : ndarray of shape (d,), float16
    basis : ndarray of shape (d, r), int8
        Levels in [−levels, levels] (stored 4-bit: :func:`pack_basis`).
    basis_scale : ndarray of shape (r,), float32
    gains : ndarray of shape (r,), float32
    """
    n, d = Z.shape
    mean64 = Z.mean(axis=0, dtype=np.float64)
    largest = float(np.abs(mean64).max(initial=0.0))
    if not largest <= float(np.finfo(np.float16).max):
        from ..exceptions import InvalidDescriptorsError

        raise InvalidDescriptorsError(
            f"whiten='shrink' stores the map's mean in float16 (|values| ≤ 65504), but a column of this "
            f"map has the mean {largest:.3g}. Normalise the rows (normalize='l2', the default) or scale the "
            "descriptors.")
    mean = mean64.astype(np.float16)
    centred = np.array(Z, dtype=np.float64)  # one float64 copy, centred in place
    centred -= mean.astype(np.float64)
    trace = float(np.einsum("ij,ij->", centred, centred)) / max(n - 1, 1)
    lam = SHRINK_LAMBDA * trace / d
    if rank == 0:
        empty = np.zeros((d, 0), dtype=np.int8)
        return mean, empty, np.zeros(0, dtype=np.float32), np.zeros(0, dtype=np.float32)
    sv, vt = _top_directions(centred, rank + 1)
    del centred
    eig_all = sv**2 / max(n - 1, 1)
    eig, vt = eig_all[:rank], vt[:rank]
    rest = float(eig_all[rank]) if eig_all.size > rank else 0.0
    gains = (np.sqrt((rest + lam) / (eig + lam)) - 1.0).astype(np.float32)
    U = vt.T  # (d, r), orthonormal columns
    scale = np.maximum(np.abs(U).max(axis=0), 1e-12) / levels
    basis = np.clip(np.rint(U / scale), -levels, levels).astype(np.int8)
    return mean, basis, scale.astype(np.float32), gains


def _top_directions(centred: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    """The top singular values and right singular vectors of the centred rows (n, d): at least k of each
    (all of them from a full SVD), never a d × d matrix.

    A randomized SVD (scikit-learn's) when k is small against min(n, d) > 500; for a wide map (d > n)
    of more than :data:`GRAM_VALUES` values, the eigen-decomposition of the n × n Gram matrix (the same
    directions, n²·d work in one matrix product instead of an SVD's bidiagonalisation); else a full SVD.
    """
    n, d = centred.shape
    if k < min(n, d) // 2 and min(n, d) > 500:
        from sklearn.utils.extmath import randomized_svd

        _, sv, vt = randomized_svd(centred, k, random_state=0)
        return sv, vt
    if d > n and n * d > GRAM_VALUES:
        eig, U = np.linalg.eigh(centred @ centred.T)
        eig, U = eig[::-1][:k], U[:, ::-1][:, :k]
        sv = np.sqrt(np.maximum(eig, 0.0))
        vt = U.T @ centred
        # A direction of zero variance has a gain of 0 (module docstring): any vector serves; 0 is stored.
        vt /= np.where(sv > 0, sv, np.inf)[:, None]
        return sv, vt
    _, sv, vt = np.linalg.svd(centred, full_matrices=False)
    return sv, vt


def apply_shrink(Z: np.ndarray, mean: np.ndarray, basis: np.ndarray, basis_scale: np.ndarray,
                 gains: np.ndarray, U: np.ndarray | None = None) -> np.ndarray:
    """The (unnormalised) whitened rows z + U(g ⊙ Uᵀz), z = Z − μ, float32 (n, d).

    ``U`` is the dequantised basis (a runtime cache; built from ``basis`` and ``basis_scale`` when None).
    """
    z = np.asarray(Z, dtype=np.float32) - mean.astype(np.float32)
    if basis.shape[1] == 0:
        return z
    if U is None:
        U = basis.astype(np.float32) * basis_scale
    return z + ((z @ U) * gains) @ U.T
