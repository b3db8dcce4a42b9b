"""Parameter help from declarations: a new method describes only its own parameters."""

from __future__ import annotations

import numpy as np
import pytest

from btel.core.paramdocs import describe_constraints, parameter_meanings, parameter_table
from btel.core.validation import Interval, Options
from btel.methods import METHODS, make_method
from test_answers import _Fixed


class _Newcomer(_Fixed):
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
        self.answer, self.score = 0, 0.0  # what the toy method it builds on answers (not parameters)


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


def test_every_planner_takes_rows_then_features() -> None:
    """Every ``planned_bytes`` reads ``(n_rows, n_features, *, what the method chose)``: one order."""
    import inspect

    from btel.core.frontend import FrontEnd
    from btel.methods.btel.planning import planned_bytes

    planners = [FrontEnd.planned_bytes, planned_bytes]
    planners += [type(make_method(n)).planned_bytes for n in METHODS if hasattr(make_method(n), "planned_bytes")]
    assert len(planners) >= 8
    for planner in planners:
        params = [p for p in inspect.signature(planner).parameters.values() if p.name != "self"]
        assert [p.name for p in params[:2]] == ["n_rows", "n_features"], planner.__qualname__
        assert all(p.kind is p.KEYWORD_ONLY for p in params[2:]), planner.__qualname__


@pytest.mark.parametrize("constraints, words", [
    ([None, Interval(int, -1, -1), Interval(int, 1, 4096)], "None or -1 or an integer ≥ 1 and ≤ 4096"),
    ([None, Interval(int, 0, 2**31 - 1)], "None or an integer ≥ 0 and ≤ 2147483647"),
    ([Options("auto"), Interval(int, 1, None)], "'auto' or an integer ≥ 1"),
    ([Options(True, False)], "True or False"),
    ([Options("a", "b", "c")], "one of 'a', 'b', 'c'"),
    ([Interval(float, 0, 1, closed="right")], "a number > 0 and ≤ 1"),
])
def test_constraints_read_as_words(constraints, words: str) -> None:
    assert describe_constraints(constraints) == words


def test_a_long_meaning_ends_at_a_clause_or_a_word_never_inside_one() -> None:
    from btel.core.paramdocs import _plain

    sentence = ("B ≥ 1, tolerance-aware codes: the trees index blocks of B consecutive places (place // B) and "
                "predict a block's centre place, which is within B // 2 of every place of the block, so recall "
                "at that tolerance is kept.")
    short = _plain(sentence, limit=140)
    assert short.endswith(" …") and len(short) <= 140
    assert sentence.startswith(short[:-2]) and sentence[len(short) - 2] in ",;: "
    words = _plain("word " * 60, limit=50)
    assert words.endswith("word …") and len(words) <= 50
