"""A stream's answers, one frame at a time, are the batch answers row by row."""

from __future__ import annotations

import numpy as np
import pytest

from btel.datasets import synthetic_route
from btel.methods import make_method


@pytest.mark.parametrize("name, params", [("lsh", {"budget": "2KB"}), ("btel-codes", {"budget": "1KB"}),
                                          ("bruteforce", {"delta": 3})])
def test_stream_predict_is_predict_row_by_row(name: str, params: dict) -> None:
    route = synthetic_route(n_places=150, dim=24, seed=1)
    model = make_method(name, **params).fit(route.map)
    stream = model.stream()
    answers = [stream.predict(q) for q in route.queries]
    assert all(isinstance(a, int) for a in answers)
    np.testing.assert_array_equal(answers, model.predict(route.queries))
