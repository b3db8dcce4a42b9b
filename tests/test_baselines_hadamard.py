"""The seeded sign-flip + Walsh–Hadamard projection, ``lsh``'s default (btel.methods.baselines.hadamard)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.linalg import hadamard

from btel.methods.baselines.hadamard import DENSE_VALUES, ROUNDS, SignedHadamard, fwht


@pytest.mark.parametrize("D, max_factor", [(2, 64), (8, 64), (64, 64), (128, 64), (2048, 64), (64, 4),
                                           (512, 8)])
def test_fwht_is_the_orthonormal_sylvester_hadamard_transform(D, max_factor, monkeypatch) -> None:
    """One factor, two, and (with smaller factors) three or more: the Kronecker product is H_D."""
    import btel.methods.baselines.hadamard as module

    monkeypatch.setattr(module, "MAX_FACTOR", max_factor)
    assert len(module._factors(D)) == max(1, -(-(D.bit_length() - 1) // (max_factor.bit_length() - 1)))
    X = np.random.default_rng(D).standard_normal((3, D)).astype(np.float32)
    expected = X.astype(np.float64) @ hadamard(D) / np.sqrt(D)
    np.testing.assert_allclose(fwht(X), expected, atol=1e-5 * np.sqrt(D))


def test_fwht_needs_a_power_of_two_width() -> None:
    with pytest.raises(ValueError, match="power-of-two"):
        fwht(np.zeros((1, 12), dtype=np.float32))


@pytest.mark.parametrize("d, bits", [(64, 64), (64, 200), (2000, 100), (1500, 800), (1100, 1500)])
def test_apply_is_the_product_with_the_matrix_dense_or_structured(d, bits) -> None:
    """Small d·P: the dense matrix, built from d rows (P ≥ d) or P columns (P < d); large: the transform."""
    projection = SignedHadamard(d, bits, seed=3)
    assert (projection._dense is not None) == (d * bits <= DENSE_VALUES)   # both paths are covered
    X = np.random.default_rng(0).standard_normal((7, d)).astype(np.float32)
    R = projection.matrix()
    assert R.shape == (d, bits) and R.dtype == np.float32
    np.testing.assert_allclose(projection.apply(X), X @ R, atol=1e-4)
    np.testing.assert_array_equal(SignedHadamard(d, bits, seed=3).matrix(), R)   # regenerated from the seed
    assert not np.allclose(SignedHadamard(d, bits, seed=4).matrix(), R)
    assert projection.signs.shape == (-(-bits // projection.width), ROUNDS, projection.width)


@pytest.mark.parametrize("d", [64, 100, 500])
def test_every_block_is_an_orthogonal_transform_of_the_padded_space(d) -> None:
    projection = SignedHadamard(d, 3 * 512, seed=1)
    D = projection.width
    assert D == 1 << (d - 1).bit_length()
    R = projection.matrix()
    for start in range(0, R.shape[1], D):
        block = R[:, start : start + D].astype(np.float64)
        # The first d rows of an orthogonal D × D matrix: orthonormal rows, so each block keeps lengths.
        np.testing.assert_allclose(block @ block.T, np.eye(d), atol=1e-5)
        if d == D:  # and then orthonormal columns too: D orthogonal hyperplanes
            np.testing.assert_allclose(block.T @ block, np.eye(D), atol=1e-5)
    # The blocks are drawn independently: no two share their hyperplanes.
    assert not np.allclose(R[:, :D], R[:, D : 2 * D])


@settings(max_examples=25, deadline=None)
@given(d=st.integers(1, 300), seed=st.integers(0, 2**31 - 1))
def test_a_whole_block_keeps_every_row_s_length(d: int, seed: int) -> None:
    projection = SignedHadamard(d, 1 << max(d - 1, 1).bit_length(), seed)
    x = np.random.default_rng(seed).standard_normal((2, d)).astype(np.float32)
    lengths = np.linalg.norm(projection.apply(x), axis=1)
    np.testing.assert_allclose(lengths, np.linalg.norm(x, axis=1), rtol=1e-4)


def test_sign_bits_estimate_the_angle() -> None:
    """Charikar's property: the share of differing sign bits is θ/π for vectors at angle θ."""
    rng = np.random.default_rng(0)
    d = 300
    u = rng.standard_normal(d)
    w = rng.standard_normal(d)
    w -= (w @ u) / (u @ u) * u
    for theta in (0.3, 1.0, 2.0):
        v = np.cos(theta) * u / np.linalg.norm(u) + np.sin(theta) * w / np.linalg.norm(w)
        X = np.stack([u / np.linalg.norm(u), v]).astype(np.float32)
        shares = []
        for seed in range(10):
            Y = SignedHadamard(d, 4096, seed).apply(X) > 0
            shares.append(np.mean(Y[0] != Y[1]))
        assert np.mean(shares) == pytest.approx(theta / np.pi, abs=0.01)
