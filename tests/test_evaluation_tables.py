"""The console table: one line per row in a log, blocks of columns that fit on a narrow terminal."""

from __future__ import annotations

import numpy as np
import pytest

import btel.evaluation as ev
from btel.datasets import synthetic_route
from btel.evaluation.tables import format_table, terminal_width
from btel.methods import make_method


@pytest.fixture(scope="module")
def rows() -> list:
    r = synthetic_route(300, 32, seed=0)
    return [ev.evaluate(make_method(name, budget=budget), r.map, r.queries, name=name, tolerances=(0, 2, 10))
            for name, budget in (("lsh", "2KB"), ("pq", "4KB"))]


def test_a_table_without_a_width_keeps_one_line_per_row(rows) -> None:
    table = format_table(rows)
    lsh = [line for line in table.splitlines() if line.startswith("lsh")]
    assert len(lsh) == 1 and "recall@10" in table.splitlines()[0] and "R@100%P" in table.splitlines()[0]


@pytest.mark.parametrize("width", [60, 80, 120])
def test_a_narrow_terminal_gets_blocks_that_fit_each_led_by_the_method(rows, width: int) -> None:
    table = format_table(rows, width=width)
    assert max(len(line) for line in table.splitlines()) <= width
    one_block = format_table(rows)
    # Every cell of the one-block table is somewhere in the blocks, each block's rows led by the method.
    for name in ("lsh", "pq"):
        cells = [line.split()[1:] for line in one_block.splitlines() if line.startswith(name)][0]
        blocks = [line.split()[1:] for line in table.splitlines() if line.startswith(name)]
        assert len(blocks) > 1 and sum(blocks, []) == cells
    headers = [line for line in table.splitlines() if line.startswith("method")]
    assert len(headers) == sum(line.startswith("lsh") for line in table.splitlines())


def test_the_terminal_width_comes_from_columns_on_a_terminal_only(monkeypatch: pytest.MonkeyPatch) -> None:
    import io
    import sys

    monkeypatch.setenv("COLUMNS", "77")
    monkeypatch.setattr(sys, "stdout", io.StringIO())  # a pipe or a file: one line per row, whatever COLUMNS says
    assert terminal_width() == 0
    monkeypatch.setattr(sys.stdout, "isatty", lambda: True)
    assert terminal_width() == 77


def test_the_predictions_csv_of_a_ground_truth_without_any_positive_marks_every_query() -> None:
    """Positives that are all empty (the readers refuse such files; Python may build one): -1, no IndexError."""
    from btel.datasets import GroundTruth
    from btel.evaluation.records import EvaluationResult
    from btel.evaluation.tables import predictions_csv_text

    result = EvaluationResult(name="m", n_queries=3, predictions=np.array([0, 1, 2]),
                              ground_truth=GroundTruth.from_positives([[], [], []], n_map=3))
    lines = predictions_csv_text(result).splitlines()
    assert lines[0].startswith("query,prediction,positive,correct")
    assert [line.split(",")[2:4] for line in lines[1:]] == [["-1", "0"]] * 3


def test_precision_recall_areas_of_a_row_with_one_score_for_every_query_are_marked() -> None:
    """A method whose scores carry no confidence (every query's top-1 scored alike) gets an AUC-PR:VB of one
    threshold, which can be the highest area of a table beside a tiny R@1; the table says so."""
    from btel.evaluation.tables import ONE_SCORE_MARK

    class OneScore:  # a method whose search gives every query's best place the same score
        def __init__(self, inner) -> None:
            self.inner = inner

        def __getattr__(self, name):
            return getattr(self.inner, name)

        def search(self, Q, k=10):
            scores, places = self.inner.search(Q, k)
            return np.zeros_like(scores), places

    r = synthetic_route(300, 32, seed=0)
    flat = ev.evaluate(OneScore(make_method("lsh", budget="2KB").fit(r.map)), r.map, r.queries, name="flat",
                       fit=False, tolerances=(0, 2))
    ranked = ev.evaluate(make_method("lsh", budget="2KB"), r.map, r.queries, name="ranked", tolerances=(0, 2))
    assert len(flat.pr_curve["recall"]) == 1 and len(ranked.pr_curve["recall"]) > 1
    text = format_table([flat, ranked])
    flat_line = next(line for line in text.splitlines() if line.startswith("flat"))
    ranked_line = next(line for line in text.splitlines() if line.startswith("ranked"))
    assert flat_line.count(ONE_SCORE_MARK) == 3 and ONE_SCORE_MARK not in ranked_line
    assert f"{ONE_SCORE_MARK} every query's top-1 has the same score" in text
    assert ONE_SCORE_MARK not in format_table([ranked])  # no mark, no legend line
