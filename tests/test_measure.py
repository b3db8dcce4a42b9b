"""One way to measure (issue 38): measure(), timed_fit(), and no second fitting/timing path."""

from __future__ import annotations

import ast
from pathlib import Path

import numpy as np
import pytest

import btel
from btel.datasets import synthetic_route
from btel.evaluation import measure, timed_fit
from btel.evaluation.records import EvaluationResult, does_not_fit_status
from btel.exceptions import BudgetTooSmallError
from btel.methods import METHODS, make_method

SRC = Path(btel.__file__).resolve().parent
#: Clocks read to time something.
CLOCKS = {"perf_counter", "perf_counter_ns", "monotonic", "process_time", "time"}
#: The calls whose duration is a measurement.
TIMED_CALLS = {"fit", "predict", "rank", "search", "predict_sequence"}
#: The functions that may time them: measure() (its ranking), timed_fit() and the query timing.
ALLOWED = {("evaluation/measure.py", "measure"), ("evaluation/measure.py", "timed_fit"),
           ("evaluation/timing.py", "_time_queries")}


def _own_nodes(fn: ast.AST):
    """The nodes of a function's body, not those of the functions and classes defined in it."""
    nested = (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda, ast.ClassDef)
    stack = [c for c in fn.body if not isinstance(c, nested)]
    while stack:
        node = stack.pop()
        yield node
        stack.extend(c for c in ast.iter_child_nodes(node) if not isinstance(c, nested))


def timing_paths(source: str) -> list[str]:
    """Functions of ``source`` that read a clock and call fit/predict/rank/search in the same body."""
    found = []
    for fn in ast.walk(ast.parse(source)):
        if not isinstance(fn, (ast.FunctionDef, ast.AsyncFunctionDef)):
            continue
        clock = timed = False
        for node in _own_nodes(fn):
            if not isinstance(node, ast.Call):
                continue
            f = node.func
            if isinstance(f, ast.Attribute) and f.attr in TIMED_CALLS:
                timed = True
            name = f.attr if isinstance(f, ast.Attribute) else getattr(f, "id", None)
            owner = getattr(f, "value", None)
            via_time = isinstance(f, ast.Name) or (isinstance(owner, ast.Name) and owner.id == "time")
            clock = clock or (name in CLOCKS and via_time)
        if clock and timed:
            found.append(fn.name)
    return found


def test_the_scanner_finds_a_hand_timed_fit() -> None:
    toy = ("import time\n"
           "def fit_row(model, X):\n"
           "    start = time.perf_counter()\n"
           "    model.fit(X)\n"
           "    return time.perf_counter() - start\n"
           "def fine(model, X):\n"
           "    def later():\n"
           "        return time.perf_counter()\n"
           "    return model.fit(X)\n")
    assert timing_paths(toy) == ["fit_row"]


def test_no_second_fitting_or_timing_path_outside_measure() -> None:
    """Every layer above the methods times fits and queries through btel.evaluation.measure/timing.

    The methods themselves are left out: an estimator records its own ``fit_time_`` attribute
    (part of the model, not a measurement of the harness).
    """
    offenders = []
    for path in sorted(SRC.rglob("*.py")):
        rel = path.relative_to(SRC).as_posix()
        if rel.startswith("methods/"):
            continue
        offenders += [f"{rel}:{name}" for name in timing_paths(path.read_text(encoding="utf-8"))
                      if (rel, name) not in ALLOWED]
    assert not offenders, f"fits or queries timed outside btel.evaluation.measure: {offenders}"


def test_measure_takes_a_fitted_model_and_its_fit_time() -> None:
    route = synthetic_route(120, 16, seed=3)
    model = make_method("pq", budget="4KB")
    seconds = timed_fit(model, route.map)
    assert seconds > 0 and model.n_places_ == 120
    result = measure(model, None, route.queries, fit=False, fit_time_s=seconds, labels={"part": "x"}, ks=(1,))
    fresh = measure(make_method("pq", budget="4KB"), route.map, route.queries, ks=(1,))
    assert result.fit_time_s == seconds and result.labels == {"part": "x"}
    np.testing.assert_array_equal(result.predictions, fresh.predictions)  # seeded: the same model either way
    assert result.recall == fresh.recall and result.choice is None


def test_a_row_of_auto_names_its_choice_reason_and_parameters() -> None:
    route = synthetic_route(200, 32, seed=0)
    result = measure(make_method("auto", budget="8KB"), route.map, route.queries, ks=(1,))
    choice = result.to_dict()["choice"]
    assert choice["method"] in METHODS and choice["method"] != "auto"
    assert isinstance(choice["reason"], str) and choice["reason"] and isinstance(choice["params"], dict)
    assert EvaluationResult.from_dict(result.to_dict()).choice == choice


def test_the_does_not_fit_status_comes_from_one_place() -> None:
    route = synthetic_route(200, 32, seed=0)
    with pytest.raises(BudgetTooSmallError) as info:
        make_method("btel-c", budget="64B").fit(route.map)
    row = EvaluationResult.does_not_fit("btel-c", info.value, n_map=200)
    assert row.status == "does not fit" and row.minimum_bytes == info.value.minimum > 64
    assert does_not_fit_status(info.value.minimum) == f"does not fit (needs ≥ {info.value.minimum} B)"
    offenders = [p.relative_to(SRC).as_posix() for p in SRC.rglob("*.py")
                 if "does not fit (needs ≥" in p.read_text(encoding="utf-8") and p.name != "records.py"]
    assert not offenders, offenders


@pytest.mark.realdata
def test_measure_on_gardens_point_equals_its_parts(gardenspoint_netvlad) -> None:
    """measure() on real descriptors: its predictions are the model's own, its fit time is timed_fit's."""
    X, Q = gardenspoint_netvlad
    result = measure(make_method("bruteforce"), X, Q, ks=(1, 5))
    np.testing.assert_array_equal(result.predictions, make_method("bruteforce").fit(X).predict(Q))
    assert result.fit_time_s > 0 and result.n_map == 200
    assert 0 < result.recall_at_k[1] <= result.recall_at_k[5]


def test_a_record_gives_the_parameters_as_given_and_what_the_fit_chose() -> None:
    """metrics.json said n_subquantizers=null for pq: what ran is what the budget planner chose, and it is
    kept apart from what was given (params as given, chosen_at_fit beside them); btel-codes' code='auto'
    was recorded as "auto" though the fit used the periodic codes."""
    from btel.datasets import synthetic_route
    from btel.evaluation import measure as measure_record
    from btel.methods import make_method

    route = synthetic_route(200, 32, seed=0)
    for name, key in (("pq", "n_subquantizers"), ("lsh", "n_bits")):
        method = make_method(name, budget="8KB")
        record = measure_record(method, route.map, route.queries, name=name)
        assert record.params[key] is None
        assert isinstance(record.chosen_at_fit[key], int) and record.chosen_at_fit[key] == method._fitted_state()[key]
        assert record.to_dict()["chosen_at_fit"][key] == record.chosen_at_fit[key]
        assert type(record).from_dict(record.to_dict()).chosen_at_fit == record.chosen_at_fit
    codes = measure_record(make_method("btel-codes", budget="8KB"), route.map, route.queries, name="codes")
    assert codes.params["code"] == "auto" and codes.chosen_at_fit["code"] == "periodic"
    assert codes.chosen_at_fit["n_features"] == 32  # its state calls it n_selected
    # pca_dim, which pq's state calls dim: a 500-D map at 16 KB is projected to a few dimensions, and says so.
    wide = np.random.default_rng(0).standard_normal((200, 500)).astype(np.float32)
    method = make_method("pq", budget="16KB")
    record = measure_record(method, wide, wide[:20], name="pq")
    assert record.chosen_at_fit["pca_dim"] == method.config_.dim < 500


def test_measure_takes_a_method_name_and_records_budgets_in_bytes() -> None:
    """measure('lsh', …) raised AttributeError ('str' has no fit); a budget given as '8KB' was recorded as the
    string; rows were named by class (every BTEL variant 'BTELocalizer')."""
    from btel.datasets import synthetic_route
    from btel.evaluation import measure as measure_record
    from btel.methods import make_method

    route = synthetic_route(200, 32, seed=0)
    by_name = measure_record("lsh", route.map, route.queries, budget="4KB")
    assert by_name.name == "lsh" and by_name.budget == 4000 and by_name.nbytes <= 4000
    given = measure_record(make_method("pq", budget="4KB"), route.map, route.queries, budget="4KB")
    assert given.name == "pq" and given.budget == 4000
