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
    # A frontier row names its key recall (recall@2 on a route) beside the usual three.
    keyed = EvaluationResult.from_row({**row, "key": "recall@2"}, measured=result)
    assert f"recall@0={row['recall@0']:.3f} recall@2={row['recall@2']:.3f} recall@10=" in describe_row(keyed)
    assert "recall@2=" not in describe_row(labelled)


# -- a damaged metrics.json row (an edited run folder given to `btel evaluate --resume`) ---------------------

def _measured_row() -> dict:
    route = synthetic_route(80, 16, seed=0)
    result = evaluate(make_method("bruteforce"), route.map, route.queries, name="nn", curve_max=5)
    return json.loads(json.dumps(result.to_dict()))


@pytest.mark.parametrize("field, value", [
    ("nbytes", "5KB"), ("nbytes", -1), ("nbytes", True), ("pr_curve", "x"), ("pr_curve", {"precision": [1, "a"]}),
    ("auc_pr_vpr_bench", []), ("fit_time_s", {}), ("timing_repeats", "x"), ("timing_repeats", 1.5),
    ("query_time_s_per_query", {}), ("recall_curve", -1), ("recall_curve", [0.1, None]), ("choice", 1e308),
    ("recall", {"x": 0.1}), ("recall", {"1": "a"}), ("recall_at_k", []), ("storage_breakdown", {"codes": "x"}),
    ("params", [1]), ("reason", 5), ("reference", "no"), ("n_queries", "7"), ("name", None), ("status", 1),
])
def test_a_damaged_field_of_a_metrics_row_is_named(field: str, value: object) -> None:
    row = _measured_row()
    back = json.loads(json.dumps(EvaluationResult.from_dict(row).to_dict()))
    assert back == {**row, "ground_truth": None}  # the intact row reads back
    with pytest.raises(InvalidParameterError, match=f"'{field}'"):
        EvaluationResult.from_dict({**row, field: value})


@pytest.mark.parametrize("field, value", [("nbytes", "5KB"), ("pr_curve", "x"), ("choice", 1e308)])
def test_resume_of_an_edited_run_ends_with_one_error_line(tmp_path, field: str, value: object) -> None:
    from click.testing import CliRunner

    from btel.cli import main

    route = synthetic_route(120, 16, seed=1)
    np.save(tmp_path / "db.npy", route.map)
    np.save(tmp_path / "q.npy", route.queries)
    run = tmp_path / "run"
    done = CliRunner().invoke(main, ["evaluate", "--db", str(tmp_path / "db.npy"), "--queries", str(tmp_path / "q.npy"),
                                     "--methods", "lsh,pq", "--budget", "5KB", "--out", str(run), "--no-progress"])
    assert done.exit_code == 0, done.output
    metrics = json.loads((run / "metrics.json").read_text())
    metrics["run"]["complete"] = False
    metrics["results"][1][field] = value
    (run / "metrics.json").write_text(json.dumps(metrics))
    result = CliRunner().invoke(main, ["evaluate", "--resume", str(run)], catch_exceptions=False)
    assert result.exit_code == 2
    errors = [line for line in result.output.splitlines() if line.startswith("Error:")]
    assert len(errors) == 1 and f"'{field}'" in errors[0] and "row 'pq'" in errors[0]
    assert "Traceback" not in result.output
