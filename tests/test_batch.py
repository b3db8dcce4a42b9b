"""run_methods / make_jobs: "run these methods into a run folder" from Python (issue 38)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from btel.datasets import GroundTruth, synthetic_route
from btel.evaluation import Job, make_jobs, run_methods
from btel.evaluation.runs import safe_file_name
from btel.exceptions import InvalidParameterError, OutputExistsError
from btel.methods import make_method


def test_make_jobs_adds_the_unbudgeted_references_once() -> None:
    jobs = make_jobs(["pq", "itq"], ["4KB", "8KB"], {"pq": {"n_jobs": 1, "nbits": 8}})
    assert [j.name for j in jobs] == ["pq@4KB", "pq@8KB", "itq@4KB", "itq@8KB", "bruteforce",
                                      "bruteforce shrink"]
    assert [j.reference for j in jobs] == [False] * 4 + [True, True]
    assert jobs[0].settings == {"nbits": 8} and jobs[0].budget == 4000  # runtime parameters are not settings
    assert jobs[4].budget is None and jobs[5].method.get_params()["whiten"] == "shrink"
    assert [j.name for j in make_jobs(["bruteforce", "pq"], ["4KB"], reference=True)] == ["bruteforce", "pq"]
    with pytest.raises(InvalidParameterError, match="^pq: "):
        make_jobs(["pq"], ["4KB"], {"pq": {"nbits": -3}})


def test_run_methods_writes_a_run_that_describes_itself(tmp_path: Path) -> None:
    route = synthetic_route(150, 16, seed=2)
    said: list[str] = []
    saved = Job("mine", make_method("itq", budget="2KB").fit(route.map), fit=False)
    rows = run_methods([saved, "pq", "auto"], route.map, route.queries, out=tmp_path / "run", budgets=["2KB"],
                       ks=(1, 5), progress=False, echo=lambda text, err=False: said.append(text))
    assert [r.name for r in rows] == ["mine", "pq", "auto", "bruteforce", "bruteforce shrink"]
    assert all(r.ok for r in rows) and any("run folder:" in line for line in said)
    metrics = json.loads((tmp_path / "run" / "metrics.json").read_text())
    assert metrics["run"]["complete"] is True
    assert metrics["run"]["extra"]["ground_truth"]["source"].startswith("frame-aligned")
    by_name = {r["name"]: r for r in metrics["results"]}
    assert by_name["auto"]["choice"]["method"] not in (None, "auto") and by_name["pq"]["choice"] is None
    assert {r["positive_rule"] for r in metrics["results"]} == {"one true place per query"}
    assert (tmp_path / "run" / "predictions_bruteforce-shrink.csv").is_file()
    with pytest.raises(OutputExistsError):
        run_methods(["pq"], route.map, route.queries, out=tmp_path / "run", budgets=["2KB"], progress=False)


def test_run_methods_with_positives_records_their_rule(tmp_path: Path) -> None:
    route = synthetic_route(60, 8, seed=1)
    gt = GroundTruth.from_positives([[j, min(j + 1, 59)] for j in range(60)], n_map=60)
    rows = run_methods(["bruteforce"], route.map, route.queries, out=tmp_path / "run", ground_truth=gt,
                       ks=(1,), progress=False,
                       truth={"source": "/data/gt.npz", "rule": "positives listed per query"})
    assert rows[0].truth == {"source": "/data/gt.npz", "rule": "positives listed per query"}
    row = json.loads((tmp_path / "run" / "metrics.json").read_text())["results"][0]
    assert row["ground_truth"] == "positives" and row["positive_rule"] == "positives listed per query"
    assert row["recall"] == {} and row["recall_at_k"]["1"] == pytest.approx(rows[0].recall_at_k[1])


@pytest.mark.parametrize("name, safe", [("bruteforce shrink", "bruteforce-shrink"), ("pq@100KB", "pq-100KB"),
                                        ("a/../b", "a-..-b"), ("  ", "method"), ("btel-c", "btel-c")])
def test_file_safe_names_have_no_spaces_or_path_characters(name: str, safe: str) -> None:
    assert safe_file_name(name) == safe
    assert not set(safe_file_name(name)) & set(" /\\:@*?\"<>|")


@pytest.mark.realdata
def test_run_methods_on_gardens_point(gardenspoint_netvlad, tmp_path: Path) -> None:
    X, Q = gardenspoint_netvlad
    rows = run_methods(["pq"], X, Q, out=tmp_path / "gp", budgets=["8KB"], ks=(1, 5), progress=False)
    reference = next(r for r in rows if r.name == "bruteforce")
    np.testing.assert_array_equal(reference.predictions, make_method("bruteforce").fit(X).predict(Q))
    assert rows[0].nbytes <= 8000 and 0 < rows[0].recall_at_k[1] <= reference.recall_at_k[5]
