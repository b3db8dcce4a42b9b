"""Run folders: write_run, run_metadata and recall recomputed from the predictions a folder holds."""

from __future__ import annotations

import csv
import json
import os
import re
import shutil
import subprocess
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from btel.evaluation import EvaluationResult, evaluate
from btel.exceptions import DataNotFoundError, InvalidParameterError
from btel.methods import make_method
from btel.evaluation.runs import recompute_recall_from_csv, run_metadata, write_run


class _PlainPredictor:
    """An object with only fit/predict (no storage, no params, no ranking)."""

    def fit(self, X: Any) -> "_PlainPredictor":
        self.n_ = len(X)
        return self

    def predict(self, Q: Any) -> np.ndarray:
        return np.minimum(np.arange(len(Q)) + 1, self.n_ - 1)  # always one frame ahead


def _results() -> list[EvaluationResult]:
    rng = np.random.default_rng(0)
    X = rng.normal(size=(80, 16)).astype(np.float32)
    Q = (X + 1.0 * rng.normal(size=X.shape)).astype(np.float32)
    Q2 = (X + 1.5 * rng.normal(size=X.shape)).astype(np.float32)
    return [
        evaluate(make_method("bruteforce"), X, Q, name="NN euclid"),
        evaluate(make_method("bruteforce"), X, Q2, name="NN noisier"),
        evaluate(_PlainPredictor(), X, Q, name="ahead"),
    ]


def test_write_run_files_and_recomputed_recall(tmp_path: Path) -> None:
    results = _results()
    out = tmp_path / "run"
    report = write_run(results, out, command=["btel", "evaluate", "--out", str(out)], extra={"data": "toy"})
    names = sorted(p.name for p in out.iterdir())
    assert names == sorted(
        ["metrics.json", "metrics.csv", "predictions_NN-euclid.csv", "predictions_NN-noisier.csv",
         "predictions_ahead.csv", "recall_vs_tolerance.png", "recall_vs_storage.png", "precision_recall.png"]
    )
    metrics = json.loads(report.metrics_json.read_text())
    run = metrics["run"]
    assert run["command"] == f"btel evaluate --out {out}"
    assert run["extra"] == {"data": "toy"}
    assert {"btel", "numpy", "scikit-learn", "faiss", "python"} <= set(run["versions"])
    assert run["date_utc"] and run["platform"]
    assert run["updated_utc"] >= run["date_utc"] and run["seconds"] >= 0  # when it ended, and how long it took
    assert [r["name"] for r in metrics["results"]] == ["NN euclid", "NN noisier", "ahead"]

    for entry, result in zip(metrics["results"], results):
        recorded = {int(t): v for t, v in entry["recall"].items()}
        assert list(recorded) == [0, 1, 2, 5]  # 80 places: tolerances up to a tenth of the route
        assert recompute_recall_from_csv(report.predictions[result.name], recorded) == recorded
        assert entry["nbytes"] == result.nbytes
        assert len(entry["recall_curve"]) == 11  # t = 0..10: twice the largest tolerance, at least 10
    # The noise makes the methods disagree somewhere, so this comparison is not vacuous.
    assert results[0].recall != results[2].recall

    with open(report.metrics_csv, newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert [r["method"] for r in rows] == ["NN euclid", "NN noisier", "ahead"]
    assert float(rows[0]["recall@5"]) == results[0].recall[5]
    assert [r["status"] for r in rows] == ["ok"] * 3
    described = metrics["columns"]["metrics.csv"]  # every column of metrics.csv says what it is
    assert all(c in described or re.sub(r"@\d+$", "@t", c) in described or re.sub(r"@\d+$", "@K", c) in described
               for c in rows[0])
    with open(report.predictions["NN euclid"], newline="") as fh:
        header = {re.sub(r"^rank_\d+$", "rank_K", c) for c in next(csv.reader(fh))}
        assert header <= set(metrics["columns"]["predictions_<method>.csv"]) and "rank_K" in header
    assert int(rows[0]["nbytes"]) == results[0].nbytes and rows[2]["nbytes"] == ""
    assert float(rows[1]["R@5"]) == results[1].recall_at_k[5] and rows[2]["R@5"] == ""  # no rank(): R@1 only
    with open(report.predictions["ahead"], newline="") as fh:
        first = next(csv.DictReader(fh))
    assert first == {"query": "0", "prediction": "1", "true": "0", "correct": "0"}


def test_predictions_carry_an_explicit_true_place(tmp_path: Path) -> None:
    X = np.random.default_rng(1).normal(size=(30, 8)).astype(np.float32)
    truth = np.roll(np.arange(30), 3)
    result = evaluate(make_method("bruteforce"), X, X[truth], ground_truth=truth, name="NN")
    report = write_run([result], tmp_path / "run", plots=False)
    with open(report.predictions["NN"], newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert [int(r["true"]) for r in rows] == truth.tolist()
    assert recompute_recall_from_csv(report.predictions["NN"], result.recall) == result.recall


def test_write_run_refuses_to_overwrite(tmp_path: Path) -> None:
    results = _results()
    out = tmp_path / "run"
    write_run(results, out, plots=False)
    with pytest.raises(FileExistsError, match=str(out)):
        write_run(results[:1], out, plots=False)
    (out / "notes.txt").write_text("keep me")
    write_run(results[:1], out, overwrite=True, plots=False)
    # Stale files of the earlier run are gone; the user's own file is kept.
    assert not (out / "predictions_ahead.csv").exists()
    assert (out / "predictions_NN-euclid.csv").exists() and (out / "notes.txt").exists()
    # An existing empty folder is fine.
    (tmp_path / "empty").mkdir()
    write_run(results[:1], tmp_path / "empty", plots=False)


def test_overwrite_removes_only_what_the_previous_run_wrote(tmp_path: Path) -> None:
    """A file named like a run's that the run did not write, and a folder holding no btel run, are kept."""
    from btel.exceptions import OutputExistsError

    results = _results()
    out = tmp_path / "run"
    write_run(results, out, plots=False)
    (out / "predictions_mine.csv").write_text("my own\n")
    write_run(results[:1], out, overwrite=True, plots=False)
    assert (out / "predictions_mine.csv").read_text() == "my own\n"
    foreign = tmp_path / "mine"
    foreign.mkdir()
    (foreign / "metrics.json").write_text('{"mine": 1}')
    (foreign / "predictions_x.csv").write_text("kept\n")
    with pytest.raises(OutputExistsError, match="no btel run"):
        write_run(results, foreign, overwrite=True, plots=False)
    assert (foreign / "metrics.json").read_text() == '{"mine": 1}' and (foreign / "predictions_x.csv").exists()


def test_write_run_rejects_clashing_names_and_no_results(tmp_path: Path) -> None:
    results = _results()
    results[1].name = "NN/euclid"  # same file name as "NN euclid" once made file-safe
    with pytest.raises(InvalidParameterError, match="not distinct"):
        write_run(results, tmp_path / "run")
    assert not (tmp_path / "run").exists()
    with pytest.raises(InvalidParameterError, match="at least one"):
        write_run([], tmp_path / "run")


def test_run_metadata_and_recompute_errors(tmp_path: Path) -> None:
    meta = run_metadata(["btel", "demo", "--out", "a b"])
    assert meta["command"] == "btel demo --out 'a b'"
    assert meta["versions"]["btel"] and meta["cpu_count"]
    # where it ran and with how many threads, and which source: a run that describes itself
    assert meta["cwd"] == os.getcwd() and isinstance(meta["threads"]["libraries"], list)
    assert any(lib["user_api"] == "blas" and lib["num_threads"] >= 1 for lib in meta["threads"]["libraries"])
    checkout = Path(__file__).resolve().parents[1]
    if (checkout / ".git").exists() and shutil.which("git"):  # an editable install from a clone (CI's)
        head = subprocess.run(["git", "-C", str(checkout), "rev-parse", "HEAD"], capture_output=True, text=True)
        assert meta["btel_commit"] == head.stdout.strip()
    else:
        assert meta["btel_commit"] is None
    with pytest.raises(DataNotFoundError, match="does not exist"):
        recompute_recall_from_csv(tmp_path / "missing.csv")
    (tmp_path / "other.csv").write_text("a,b\n1,2\n")
    with pytest.raises(DataNotFoundError, match="not a predictions file"):
        recompute_recall_from_csv(tmp_path / "other.csv")


@pytest.mark.realdata
def test_run_folder_of_nordland_pixels(nordland_pixels: tuple[np.ndarray, np.ndarray], tmp_path: Path) -> None:
    summer, winter = nordland_pixels
    result = evaluate(make_method("bruteforce"), summer[::4], winter[::4], name="pixel NN")
    report = write_run([result], tmp_path / "run", command="pytest")
    metrics = json.loads(report.metrics_json.read_text())
    recomputed = recompute_recall_from_csv(report.predictions["pixel NN"])
    assert {int(t): v for t, v in metrics["results"][0]["recall"].items()} == recomputed
    assert recomputed[10] > 3 * 21 / summer[::4].shape[0]  # far above chance: frames are aligned


def test_an_experiment_rows_csv_writes_structured_cells_as_json() -> None:
    """results.csv held a front end as Python's repr ("{'normalize': 'l2', 'whiten': None}")."""
    from btel.evaluation.tables import rows_csv_text

    row = EvaluationResult.from_row({"method": "lsh", "status": "ok", "front_end": {"normalize": "l2", "whiten": None}})
    cells = next(csv.DictReader(rows_csv_text([row]).splitlines()))
    assert json.loads(cells["front_end"]) == {"normalize": "l2", "whiten": None}


def test_a_run_on_a_busy_machine_says_so_and_records_the_load(tmp_path, monkeypatch) -> None:
    """Fit times of one method varied 10× between two runs under load, and nothing in the output said why."""
    import json as _json

    from click.testing import CliRunner

    import btel.evaluation.runs as runs
    from btel.cli import main

    monkeypatch.setattr(runs, "load_average", lambda: [9.5, 7.0, 4.0])
    monkeypatch.setattr("os.cpu_count", lambda: 2)
    out = tmp_path / "busy"
    result = CliRunner().invoke(main, ["demo", "--places", "120", "--dim", "16", "--methods", "lsh", "--budget", "1KB",
                                       "--no-reference", "--no-progress", "--out", str(out)])
    assert result.exit_code == 0, result.output
    assert "note: the machine is busy (load average 9.5 on 2 cores)" in result.output
    run = _json.loads((out / "metrics.json").read_text())["run"]
    assert run["load_average"] == [9.5, 7.0, 4.0] and run["load_average_updated"] == [9.5, 7.0, 4.0]
    shown = CliRunner().invoke(main, ["show", str(out)])
    assert "load average 9.50 at the start, 9.50 at the last write" in shown.output
    monkeypatch.setattr(runs, "load_average", lambda: [1.5, 1.0, 1.0])  # below the cores: no note
    quiet = CliRunner().invoke(main, ["demo", "--places", "120", "--dim", "16", "--methods", "lsh", "--budget", "1KB",
                                      "--no-reference", "--no-progress", "--out", str(tmp_path / "idle")])
    assert quiet.exit_code == 0 and "machine is busy" not in quiet.output
