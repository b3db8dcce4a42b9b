"""Parameter help from declarations: a new method describes only its own parameters."""

from __future__ import annotations

import numpy as np
import pytest

from btel.core.paramdocs import parameter_meanings, parameter_table
from btel.core.validation import Interval
from btel.methods import METHODS, make_method
from btel.methods.base import ArraySpec, PlaceLocalizer


class _Newcomer(PlaceLocalizer):
    """A method as a newcomer writes it: its docstring lists its own parameter only.

    Parameters
    ----------
    budget : int or str, optional
        Bytes the newcomer may store.
    depth : int
        How deep it looks. A second sentence that the help leaves out.
    """

    _parameter_constraints = {"depth": [Interval(int, 1, 9)]}

    def __init__(self, *, budget: int | str | None = None, depth: int = 3) -> None:
        self.budget = budget
        self.depth = depth

    def _fit(self, X, places, n_places, budget, reserved) -> None:
        pass

    def _search(self, Q: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
        return np.zeros((Q.shape[0], k)), np.zeros((Q.shape[0], k), dtype=np.int64)

    def _stored_arrays(self) -> dict[str, np.ndarray]:
        return {}

    def _array_specs(self, state) -> dict[str, ArraySpec]:
        return {}

    def _restore(self, arrays, state) -> None:
        pass


def test_a_new_method_needs_no_docstring_entry_for_the_shared_parameters() -> None:
    table = {name: (allowed, meaning) for name, _, allowed, meaning, _ in parameter_table(_Newcomer())}
    assert set(table) == {"budget", "depth", "normalize", "whiten", "delta"}
    assert table["depth"] == ("an integer ≥ 1 and ≤ 9", "How deep it looks.")
    assert table["budget"][1] == "Bytes the newcomer may store."  # its own words win
    assert table["budget"][0].startswith("a byte budget")  # declared once, on the base class
    assert table["whiten"][1].startswith("PCA-whitening") and table["delta"][1].startswith("Delta descriptors")
    assert "l2" in table["normalize"][0]


def test_the_budget_constraint_comes_from_the_base_class() -> None:
    from btel.exceptions import InvalidParameterError

    with pytest.raises(InvalidParameterError, match="budget must be"):  # _Newcomer declares only depth
        _Newcomer(budget=[1, 2]).fit(np.ones((4, 3), dtype=np.float32))


def test_a_shared_docstring_entry_yields_to_a_declared_meaning() -> None:
    class Documented(_Newcomer):
        """Doc.

        Parameters
        ----------
        normalize, whiten, delta
            The front end.
        depth : int
            Depth.
        """

    meanings = parameter_meanings(Documented)
    assert meanings["depth"] == "Depth." and meanings["whiten"].startswith("PCA-whitening")


@pytest.mark.parametrize("name", list(METHODS))
def test_every_registered_parameter_has_allowed_values_and_a_meaning(name: str) -> None:
    rows = parameter_table(make_method(name))
    assert rows and all(meaning and allowed for _, _, allowed, meaning, _ in rows), name
