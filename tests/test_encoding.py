"""Binary tree codes and the two decoders (SPEC §2)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from btel.methods.btel.encoding import bit_codes, decode, decode_constrained, decode_soft, encode, n_bits_for
from btel.exceptions import InvalidParameterError, NotEnoughPlacesError

# N from 2 to 2**16, and for each N a list of valid indices.
n_places = st.integers(min_value=2, max_value=1 << 16)


@st.composite
def n_and_indices(draw, max_n: int = 1 << 16, max_size: int = 50):
    n = draw(st.integers(min_value=2, max_value=max_n))
    idx = draw(st.lists(st.integers(min_value=0, max_value=n - 1), min_size=1, max_size=max_size))
    return n, np.asarray(idx, dtype=np.int64)


def brute_force_soft(margins: np.ndarray, n: int) -> np.ndarray:
    """argmax over i < N of Σ_k m_k (2·bit_k(i) − 1), by looping over every i (ties: smallest i)."""
    b = n_bits_for(n)
    best = np.zeros(margins.shape[0], dtype=np.int64)
    best_score = np.full(margins.shape[0], -np.inf)
    for i in range(n):
        signs = np.array([2 * ((i >> (b - 1 - k)) & 1) - 1 for k in range(b)], dtype=np.float64)
        score = margins @ signs
        better = score > best_score
        best[better] = i
        best_score[better] = score[better]
    return best


# ----------------------------------------------------------------------------- depth and codes
@pytest.mark.parametrize(
    ("n", "b"),
    [(1, 1), (2, 1), (3, 2), (4, 2), (5, 3), (8, 3), (9, 4), (1000, 10), (1024, 10), (1025, 11), (65536, 16), (65537, 17)],
)
def test_n_bits_for_is_ceil_log2_with_minimum_one(n: int, b: int) -> None:
    assert n_bits_for(n) == b


@settings(deadline=None)
@given(n=st.integers(min_value=2, max_value=1 << 40))
def test_n_bits_for_holds_n_minus_one_and_no_fewer(n: int) -> None:
    b = n_bits_for(n)
    assert (n - 1) < (1 << b)
    assert b == 1 or (n - 1) >= (1 << (b - 1))


def test_encode_is_msb_first() -> None:
    bits = encode(np.array([0, 1, 4, 6]), 3)
    np.testing.assert_array_equal(bits, [[0, 0, 0], [0, 0, 1], [1, 0, 0], [1, 1, 0]])
    assert bits.dtype == np.uint8


@settings(max_examples=300, deadline=None)
@given(n_and_indices())
def test_encode_decode_round_trip(case) -> None:
    n, idx = case
    b = n_bits_for(n)
    bits = encode(idx, b)
    assert bits.shape == (idx.size, b)
    assert set(np.unique(bits)) <= {0, 1}
    np.testing.assert_array_equal(decode(bits), idx)


@settings(max_examples=100, deadline=None)
@given(n=n_places)
def test_round_trip_of_extreme_indices(n: int) -> None:
    # The largest index N−1 uses every bit of the code; 0 uses none.
    idx = np.array([0, n // 2, n - 1])
    np.testing.assert_array_equal(decode(encode(idx, n_bits_for(n))), idx)


@pytest.mark.parametrize("n", [2, 3, 5, 17, 100])
def test_bit_codes_are_signed_codes_of_every_index(n: int) -> None:
    codes = bit_codes(n)
    assert codes.shape == (n, n_bits_for(n)) and codes.dtype == np.int8
    np.testing.assert_array_equal(codes, 2 * encode(np.arange(n), n_bits_for(n)).astype(np.int8) - 1)


# ----------------------------------------------------------------------------- constrained decode
@pytest.mark.parametrize(
    ("n", "margins", "expected"),
    [
        # N = 5 → N−1 = 100: all-ones would be 7; the 2nd and 3rd bits are forced to 0.
        (5, [1.0, 1.0, 1.0], 4),
        # A 0 at the MSB frees the lower bits: 011 = 3.
        (5, [-1.0, 1.0, 1.0], 3),
        # N = 6 → N−1 = 101: 111 → 101 (2nd bit forced), the last bit stays free.
        (6, [1.0, 1.0, 1.0], 5),
        (6, [1.0, 1.0, -1.0], 4),
        # N = 3 → N−1 = 10: 11 → 10.
        (3, [2.0, 0.5], 2),
        # Zero margin reads as bit 0 ("not positive").
        (8, [0.0, 1.0, 0.0], 2),
    ],
)
def test_constrained_decode_hand_made(n: int, margins: list[float], expected: int) -> None:
    assert decode_constrained(np.array([margins]), n)[0] == expected


@settings(max_examples=150, deadline=None)
@given(
    data=st.data(),
    n=n_places,
)
def test_constrained_decode_is_always_a_valid_index(data, n: int) -> None:
    b = n_bits_for(n)
    rows = data.draw(st.integers(min_value=1, max_value=20))
    values = data.draw(
        st.lists(st.floats(allow_nan=True, allow_infinity=True), min_size=rows * b, max_size=rows * b)
    )
    margins = np.array(values, dtype=np.float64).reshape(rows, b)
    out = decode_constrained(margins, n)
    assert out.dtype == np.int64 and out.shape == (rows,)
    assert np.all((out >= 0) & (out < n))
    # Forcing bits to 0 can only lower the raw reading of the signs.
    raw = decode((np.nan_to_num(margins, nan=-1.0) > 0).astype(np.uint8))
    assert np.all(out <= raw)


@settings(max_examples=150, deadline=None)
@given(
    case=n_and_indices(max_size=20),
    magnitude=st.floats(min_value=1e-6, max_value=1e6),
    data=st.data(),
)
def test_constrained_decode_is_exact_for_margins_with_the_signs_of_a_valid_code(case, magnitude, data) -> None:
    n, idx = case
    b = n_bits_for(n)
    scale = np.array(
        data.draw(st.lists(st.floats(min_value=1e-3, max_value=1e3), min_size=idx.size * b, max_size=idx.size * b))
    ).reshape(idx.size, b)
    margins = (2.0 * encode(idx, b) - 1.0) * magnitude * scale
    np.testing.assert_array_equal(decode_constrained(margins, n), idx)


def test_constrained_decode_accepts_zero_one_bits() -> None:
    idx = np.arange(11)
    np.testing.assert_array_equal(decode_constrained(encode(idx, 4), 11), idx)


# ----------------------------------------------------------------------------- soft decode
@settings(max_examples=200, deadline=None)
@given(data=st.data(), n=st.integers(min_value=2, max_value=300))
def test_soft_decode_equals_brute_force_argmax(data, n: int) -> None:
    # Integer margins keep float32 sums exact, so ties are compared too (both pick the smallest i).
    b = n_bits_for(n)
    rows = data.draw(st.integers(min_value=1, max_value=8))
    values = data.draw(st.lists(st.integers(min_value=-1000, max_value=1000), min_size=rows * b, max_size=rows * b))
    margins = np.array(values, dtype=np.float64).reshape(rows, b)
    out = decode_soft(margins, n)
    assert np.all((out >= 0) & (out < n))
    np.testing.assert_array_equal(out, brute_force_soft(margins, n))


@settings(max_examples=200, deadline=None)
@given(data=st.data(), n=st.integers(min_value=2, max_value=5000))
def test_soft_decode_is_valid_and_maximises_the_score_for_float_margins(data, n: int) -> None:
    b = n_bits_for(n)
    rows = data.draw(st.integers(min_value=1, max_value=8))
    values = data.draw(
        st.lists(st.floats(min_value=-1e3, max_value=1e3), min_size=rows * b, max_size=rows * b)
    )
    margins = np.array(values, dtype=np.float64).reshape(rows, b)
    out = decode_soft(margins, n)
    assert np.all((out >= 0) & (out < n))
    scores = margins @ bit_codes(n).astype(np.float64).T  # (rows, N)
    best = scores.max(axis=1)
    # float32 scoring inside decode_soft: the chosen index is optimal up to float32 rounding.
    tol = 1e-5 * np.abs(margins).sum(axis=1) + 1e-9
    assert np.all(scores[np.arange(rows), out] >= best - tol)


@settings(deadline=None)
@given(case=n_and_indices(max_n=4000, max_size=20))
def test_soft_decode_is_exact_for_a_valid_code(case) -> None:
    n, idx = case
    margins = 2.0 * encode(idx, n_bits_for(n)) - 1.0
    np.testing.assert_array_equal(decode_soft(margins, n), idx)


def test_soft_decode_can_differ_from_constrained() -> None:
    # N = 5 (codes 000..100), margins (+0.1, +5, +5): constrained reads the weak MSB first → 4 = 100;
    # soft weighs all bits: 011 scores −0.1 + 5 + 5 = 9.9, more than 100's 0.1 − 5 − 5.
    margins = np.array([[0.1, 5.0, 5.0]])
    assert decode_constrained(margins, 5)[0] == 4
    assert decode_soft(margins, 5)[0] == 3


def test_soft_decode_chunks_give_the_same_result() -> None:
    rng = np.random.default_rng(0)
    margins = rng.standard_normal((100, n_bits_for(777)))
    np.testing.assert_array_equal(decode_soft(margins, 777, chunk_size=7), decode_soft(margins, 777))


# ----------------------------------------------------------------------------- bad input
def test_encode_rejects_indices_outside_the_code() -> None:
    with pytest.raises(InvalidParameterError, match=r"\[0, 2\*\*3\)"):
        encode(np.array([8]), 3)
    with pytest.raises(InvalidParameterError, match=r"\[0, 2\*\*3\)"):
        encode(np.array([-1]), 3)
    with pytest.raises(InvalidParameterError, match="1-D"):
        encode(np.zeros((2, 2), dtype=int), 3)


def test_decode_rejects_non_2d_bits() -> None:
    with pytest.raises(InvalidParameterError, match="2-D"):
        decode(np.array([1, 0, 1]))


@pytest.mark.parametrize("decoder", [decode_constrained, decode_soft])
def test_decoders_reject_bad_margins(decoder) -> None:
    with pytest.raises(InvalidParameterError, match="needs 3 bit margins"):
        decoder(np.zeros((2, 4)), 5)
    with pytest.raises(InvalidParameterError, match="2-D"):
        decoder(np.zeros(3), 5)
    with pytest.raises(NotEnoughPlacesError, match="at least 2"):
        decoder(np.zeros((1, 1)), 1)
    with pytest.raises(InvalidParameterError, match="n_places"):
        decoder(np.zeros((1, 1)), 0)
