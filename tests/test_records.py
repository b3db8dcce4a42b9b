"""The one result record: its flat row (experiments) and its nested dict (run folders) round-trip."""

from __future__ import annotations

import json

import numpy as np
import pytest

from btel.datasets import synthetic_route
from btel.evaluation import evaluate
from btel.exceptions import InvalidParameterError
from btel.methods import make_method
from btel.evaluation.records import EvaluationResult
from btel.evaluation.tables import describe_row, rows_csv_text


def _beyond_like_row() -> dict:
    # The cells of an experiment row in the order the experiment wrote them, labels between measured cells.
    return {"part": "nordland", "direction": "summer→winter", "method": "BTE-C", "registry_name": "btel-c",
            "n_places": 300, "budget": 16000, "options": {"block_size": 8}, "nbytes": 15966, "fit_s": 0.5,
            "status": "ok", "decoder": "single", "recall@0": 0.05, "recall@10": 0.17, "val_recall@10": 0.2,
            "R@10": 0.585, "val_R@10": 0.6, "hmm": {"temperature": 1.0, "vmax": 2}}


def test_a_row_is_written_back_cell_for_cell_in_its_order() -> None:
    row = _beyond_like_row()
    record = EvaluationResult.from_row(json.loads(json.dumps(row)))
    assert record.name == "BTE-C" and record.n_map == 300 and record.nbytes == 15966 and record.fit_time_s == 0.5
    assert record.recall == {0: 0.05, 10: 0.17} and record.recall_at_k == {10: 0.585}
    assert record.labels["val_recall@10"] == 0.2 and record.labels["direction"] == "summer→winter"
    assert list(record.to_row().items()) == list(row.items())
    not_fit = {"method": "PQ", "n_places": 300, "budget": 16000, "status": "does not fit (needs ≥ 30668 B)",
               "nbytes": None, "minimum_bytes": 30668}
    back = EvaluationResult.from_row(not_fit)
    assert not back.ok and back.minimum_bytes == 30668 and list(back.to_row().items()) == list(not_fit.items())
    assert rows_csv_text([record, back]).splitlines()[0].split(",")[:4] == ["part", "direction", "method",
                                                                            "registry_name"]


def test_a_row_needs_its_method() -> None:
    with pytest.raises(InvalidParameterError, match="needs a 'method' cell"):
        EvaluationResult.from_row({"n_places": 3, "recall@0": 0.1})


def test_an_evaluation_and_its_row_are_one_record() -> None:
    route = synthetic_route(120, 16, seed=0)
    result = evaluate(make_method("bruteforce"), route.map, route.queries, name="nn", curve_max=20,
                      tolerances=(0, 1, 2, 5, 10, 20))  # the experiments' fixed tolerances
    row = result.to_row()
    assert row["method"] == "nn" and row["n_places"] == 120 and row["nbytes"] == result.nbytes
    assert row["recall@0"] == result.recall[0] and row["R@1"] == result.recall_at_k[1]
    assert row["query_us"] == pytest.approx(result.query_time_s_per_query * 1e6)
    # An experiment's cells on top of a measured record keep its curve and predictions.
    labelled = EvaluationResult.from_row({**row, "direction": "day→night"}, measured=result)
    assert labelled.labels == {"direction": "day→night"}
    np.testing.assert_array_equal(labelled.recall_curve, result.recall_curve)
    np.testing.assert_array_equal(labelled.predictions, result.predictions)
    assert labelled.to_dict()["recall"] == result.to_dict()["recall"]
    assert describe_row(labelled).startswith("nn [day→night]") and "recall@0=" in describe_row(labelled)
