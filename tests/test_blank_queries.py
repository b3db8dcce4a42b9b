"""A blank query frame (all zeros) is answered, with a warning that the answer is no localization."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from btel.core.rows import BlankQueryWarning
from btel.methods import make_method


@pytest.mark.parametrize("name, params", [("lsh", {"budget": "2KB"}), ("btel-codes", {"budget": "1KB"}),
                                          ("pq", {"budget": "4KB"}), ("bruteforce", {})])
def test_blank_query_rows_are_named_in_a_warning(name: str, params: dict) -> None:
    X = np.random.default_rng(0).standard_normal((120, 16)).astype(np.float32)
    model = make_method(name, **params).fit(X)
    Q = np.vstack([X[:3], np.zeros((2, 16), np.float32)])
    with pytest.warns(BlankQueryWarning, match=r"2 query rows \(3, 4\) are all zeros"):
        answers = model.predict(Q)
    assert answers.shape == (5,) and (answers[:3] == model.predict(X[:3])).all()  # the others as before
    with pytest.warns(BlankQueryWarning, match=r"1 query row \(0\) is all zeros"):
        model.stream().predict(np.zeros(16, np.float32))
    with warnings.catch_warnings():
        warnings.simplefilter("error", BlankQueryWarning)
        model.predict(X[:5])  # no blank row: no warning
