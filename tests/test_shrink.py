"""Shrinkage whitening's directions (btel.core.shrink): every route gives the top singular directions, no d × d."""

from __future__ import annotations

import numpy as np
import pytest

from btel.core.shrink import GRAM_VALUES, _top_directions, apply_shrink, fit_shrink


def _wide(n: int, d: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    X = rng.standard_normal((n, d)) * np.linspace(3.0, 0.1, d)
    return X - X.mean(axis=0)


def test_the_gram_route_gives_the_full_svd_s_values_and_directions() -> None:
    C = _wide(300, 5000)
    assert C.size > GRAM_VALUES and C.shape[1] > C.shape[0]
    sv, vt = _top_directions(C, 12)
    _, sv_full, vt_full = np.linalg.svd(C, full_matrices=False)
    assert sv.shape == (12,) and vt.shape == (12, 5000)
    np.testing.assert_allclose(sv, sv_full[:12], rtol=1e-9)
    np.testing.assert_allclose(np.abs(np.sum(vt * vt_full[:12], axis=1)), 1.0, atol=1e-9)   # up to sign


def test_a_map_of_lower_rank_gives_finite_directions() -> None:
    C = np.zeros((300, 5000))
    C[:150, 0], C[150:, 0] = 1.0, -1.0  # rank 1: every further direction has (up to rounding) no variance
    sv, vt = _top_directions(C, 4)
    assert sv[0] == pytest.approx(np.sqrt(300)) and np.all(sv[1:] <= 1e-6 * sv[0])
    assert np.isfinite(sv).all() and np.isfinite(vt).all()


@pytest.mark.parametrize("shape", [(300, 5000), (200, 500)])
def test_fit_shrink_whitens_a_wide_map_as_the_full_svd_does(shape) -> None:
    """The whitened rows (the transform's output) agree whichever route found the directions."""
    Z = _wide(*shape, seed=1).astype(np.float32)
    mean, basis, scale, gains = fit_shrink(Z, 8)
    centred = Z.astype(np.float64) - mean.astype(np.float64)
    _, sv, vt = np.linalg.svd(centred, full_matrices=False)
    out = apply_shrink(Z, mean, basis, scale, gains)
    eig = sv**2 / (shape[0] - 1)
    lam = np.sum(centred**2) / (shape[0] - 1) / shape[1]
    g = np.sqrt((eig[8] + lam) / (eig[:8] + lam)) - 1.0
    expected = centred + ((centred @ vt[:8].T) * g) @ vt[:8]
    # The stored basis is 4-bit: the whitened rows agree to its quantisation.
    cos = np.sum(out * expected, axis=1) / np.linalg.norm(out, axis=1) / np.linalg.norm(expected, axis=1)
    assert cos.min() > 0.99
