"""A fitted model copied in memory (deepcopy, pickle for a process pool) answers as the original.

What the model-files guide states: in-memory copies work for every method; files go through
``save``/``load``, which never unpickle.
"""

from __future__ import annotations

import copy
import pickle

import numpy as np
import pytest

from btel.datasets import synthetic_route
from btel.methods import METHODS, make_method


@pytest.mark.parametrize("name", list(METHODS))
def test_in_memory_copies_answer_as_the_original(name: str) -> None:
    route = synthetic_route(n_places=120, dim=16, seed=3)
    params = {"progress": False} if "progress" in make_method(name).get_params() else {}
    model = make_method(name, **params).fit(route.map)
    expected = model.search(route.queries, 3)
    for copied in (copy.deepcopy(model), pickle.loads(pickle.dumps(model))):
        scores, places = copied.search(route.queries, 3)
        np.testing.assert_array_equal(places, expected[1])
        np.testing.assert_array_equal(scores, expected[0])
