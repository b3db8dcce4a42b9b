"""top_k: the k best columns per row, best first, ties to the lowest column; k = 1 by argmax."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from btel.core.topk import top_k


@settings(max_examples=60, deadline=None)
@given(scores=arrays(np.float32, st.tuples(st.integers(1, 5), st.integers(1, 40)),
                     elements=st.integers(-3, 3)))
def test_k_1_is_the_first_maximum_of_each_row(scores: np.ndarray) -> None:
    """Small integer scores: many ties, which must go to the lowest column."""
    values, columns = top_k(scores, 1)
    assert values.dtype == np.float64 and columns.dtype == np.int64 and columns.shape == (scores.shape[0], 1)
    np.testing.assert_array_equal(columns[:, 0], [int(np.flatnonzero(row == row.max())[0]) for row in scores])
    np.testing.assert_array_equal(values[:, 0], scores.max(axis=1))


def test_k_1_ranks_nan_last_as_the_general_path_does() -> None:
    scores = np.array([[np.nan, 1.0, 3.0, 3.0], [0.0, 2.0, np.nan, -1.0]])
    values, columns = top_k(scores, 1)
    np.testing.assert_array_equal(columns[:, 0], [2, 1])
    np.testing.assert_array_equal(values[:, 0], [3.0, 2.0])


@pytest.mark.parametrize("k", [1, 3, 10])
def test_top_k_is_the_sorted_head_of_each_row(k: int) -> None:
    scores = np.random.default_rng(k).standard_normal((6, 10))
    values, columns = top_k(scores, k)
    order = np.argsort(-scores, axis=1, kind="stable")[:, :k]
    np.testing.assert_array_equal(columns, order)
    np.testing.assert_array_equal(values, np.take_along_axis(scores, order, axis=1))
