"""Weights at 32 / 16 / 8 / 4 bits: exact round trips, bounded error, bytes as counted."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from btel.exceptions import InvalidParameterError, ModelFileError
from btel.methods.codes.quantise import WEIGHT_BITS, QuantisedWeights, pack_nibbles, quantise, unpack_nibbles, weight_bytes

shapes = st.tuples(st.integers(1, 12), st.integers(1, 33))
finite = st.floats(-1e3, 1e3, allow_nan=False, width=32)


@settings(max_examples=80, deadline=None)
@given(data=st.data(), shape=shapes)
def test_nibbles_round_trip(data, shape) -> None:
    values = data.draw(arrays(np.int8, shape, elements=st.integers(-8, 7)))
    packed = pack_nibbles(values)
    assert packed.dtype == np.uint8 and packed.shape == (shape[0], -(-shape[1] // 2))
    np.testing.assert_array_equal(unpack_nibbles(packed, shape[1]), values)


@settings(max_examples=80, deadline=None)
@given(data=st.data(), shape=shapes, bits=st.sampled_from(WEIGHT_BITS))
def test_quantised_weights_round_trip_exactly(data, shape, bits) -> None:
    W = data.draw(arrays(np.float64, shape, elements=finite))
    q = quantise(W, bits)
    deq = q.dequantise()
    assert deq.dtype == np.float32 and deq.shape == shape
    # Stored bytes are what the storage rule counts.
    assert sum(a.nbytes for a in q.arrays().values()) == weight_bytes(*shape, bits)
    # Requantising the dequantised weights with the stored scales gives the stored values, bit for bit.
    again = quantise(deq, bits, scales=q.scales)
    np.testing.assert_array_equal(again.values, q.values)
    # And from the arrays of a model file.
    loaded = QuantisedWeights.from_arrays({k: v.copy() for k, v in q.arrays().items()}, bits, shape[1])
    np.testing.assert_array_equal(loaded.dequantise(), deq)
    if bits == 32:
        np.testing.assert_array_equal(deq, W.astype(np.float32))
    else:
        # Error at most half a step per row, and the row's largest weight is a full-scale value.
        step = q.scales.astype(np.float64)[:, None]
        assert np.all(np.abs(deq - W) <= 0.5 * step * (1 + 1e-5) + 1e-6 * np.abs(W))
        qmax = (1 << (bits - 1)) - 1
        peaks = np.abs(q.integers()).max(axis=1)
        representable = np.abs(W).max(axis=1) >= np.finfo(np.float32).tiny * qmax
        assert np.all(peaks[representable] == qmax) and np.all(peaks[~representable] == 0)


@pytest.mark.parametrize("bits, dtype, width", [(32, np.float32, 7), (16, np.int16, 7), (8, np.int8, 7),
                                                (4, np.uint8, 4)])
def test_stored_dtype_and_shape(bits, dtype, width) -> None:
    q = quantise(np.random.default_rng(0).normal(size=(5, 7)), bits)
    assert q.values.dtype == dtype and q.values.shape == (5, width)
    assert (q.scales is None) == (bits == 32)


def test_a_zero_row_stays_zero() -> None:
    q = quantise(np.zeros((2, 3)), 4)
    np.testing.assert_array_equal(q.dequantise(), 0)


def test_bad_input_and_bad_files_are_refused() -> None:
    with pytest.raises(InvalidParameterError, match="bits"):
        quantise(np.ones((2, 2)), 12)
    with pytest.raises(InvalidParameterError, match="finite"):
        quantise(np.array([[np.nan]]), 8)
    with pytest.raises(InvalidParameterError, match=r"\[−8, 7\]"):
        pack_nibbles(np.array([[9]]))
    good = quantise(np.ones((2, 3)), 8).arrays()
    with pytest.raises(ModelFileError, match="scales"):
        QuantisedWeights.from_arrays({**good, "scales": np.array([1.0, -1.0], np.float32)}, 8, 3)
    with pytest.raises(ModelFileError, match="±127"):
        QuantisedWeights.from_arrays({**good, "weights": np.full((2, 3), -128, np.int8)}, 8, 3)
    with pytest.raises(ModelFileError, match="NaN"):
        QuantisedWeights.from_arrays({"weights": np.array([[np.nan]], np.float32)}, 32, 1)
