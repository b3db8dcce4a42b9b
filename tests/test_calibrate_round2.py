"""Calibrated auto, round 2: a table a newcomer can read (columns, verdict), honest "queries needed",
warnings where calibration cannot decide, messages that name the fix, a bounded and visible cost."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from click.testing import CliRunner

import btel
from btel.cli import main
from btel.datasets import GroundTruth, synthetic_route
from btel.exceptions import BudgetTooSmallError, InvalidParameterError
from btel.methods import make_method
from btel.methods.auto.calibrate import CANDIDATES, MIN_SWITCH_QUERIES, decide, queries_needed
from btel.methods.auto.localizer import calibration_table


@pytest.fixture
def few_candidates(monkeypatch):
    """Three candidates (the mechanism, not the candidate list, is under test): fast fits."""
    import btel.methods.auto.calibrate as cal

    monkeypatch.setattr(cal, "CANDIDATES",
                        tuple(c for c in CANDIDATES if c[0] in ("lsh", "lsh centred", "btel-codes periodic")))


@pytest.fixture(scope="module")
def route():
    r = synthetic_route(120, 16, condition_shift=1.5, noise=0.4, seed=5)
    return r.map, r.queries


def _calibration(switched: bool) -> dict:
    rows = [
        {"candidate": "pick", "status": "ok", "score": 0.5, "role": "" if switched else "chosen", "fit_s": 0.2},
        {"candidate": "better", "status": "ok", "score": 0.7, "difference": 0.2, "wins": 25, "losses": 5,
         "p_adjusted": 0.01 if switched else 0.2, "confidence": 0.99 if switched else 0.8, "queries_needed": 300,
         "queries_needed_observed": 60, "role": "chosen" if switched else "", "fit_s": 1.0},
        {"candidate": "worse", "status": "ok", "score": 0.3, "difference": -0.2, "wins": 5, "losses": 25,
         "p_adjusted": 1.0, "confidence": 0.0, "queries_needed": 300, "queries_needed_observed": 60, "role": ""},
        {"candidate": "big", "status": "over budget", "needs": "9.0 KB"},
    ]
    if switched:
        rows[0]["role"] = "map-only pick"
    return {"n_queries": 100, "tolerance": 2, "correct_when": "within 2 places of the true place", "seeds": [0, 1],
            "alpha": 0.05, "map_only": "pick", "chosen": "better" if switched else "pick", "switched": switched,
            "rows_compared": 200, "reference_difference": 0.05, "table": rows}


def test_the_table_says_what_each_column_means_and_why_the_row_was_chosen() -> None:
    kept = calibration_table(_calibration(switched=False))
    assert "correct when within 2 places of the true place" in kept.splitlines()[0]
    assert "W/L" in kept and "25/5" in kept and "fit s" in kept
    for column in ("score:", "diff:", "W/L:", "p (adj.):", "conf.:", "n for 0.05 / n for diff:"):
        assert column in kept, column
    pick_row = next(line for line in kept.splitlines() if line.strip().startswith("pick"))
    assert pick_row.endswith("map-only pick, kept")
    assert "chosen: the map-only pick pick; the most likely better candidate, better (+0.200), reaches " \
           "confidence 0.80, short of 0.95 (about 60 queries would certify a lead that size)." in kept
    worse = next(line for line in kept.splitlines() if line.strip().startswith("worse"))
    assert " 60 " not in worse  # no "queries to certify a lead" for a candidate behind the pick
    switched = calibration_table(_calibration(switched=True))
    assert "chosen: better, ahead of the map-only pick pick by +0.200 beyond noise (adjusted p 0.010 < α = 0.05, " \
           "confidence 0.99)." in switched
    assert next(line for line in switched.splitlines() if line.strip().startswith("pick")).endswith("map-only pick")
    assert not any(line != line.rstrip() for line in switched.splitlines())


def test_queries_needed_is_none_when_the_disagreements_cannot_hold_the_difference() -> None:
    """A difference is at most the share of discordant queries: 1 discordant query of 300 cannot show 0.05."""
    assert queries_needed(1 / 300, 0.05) is None
    assert queries_needed(0.05, 0.05) is not None and queries_needed(0.3, 0.05) > 100
    table = [{"candidate": k, "status": "ok", "score": float(v.mean())} for k, v in
             {"pick": np.ones(100), "behind": np.r_[np.zeros(10), np.ones(90)]}.items()]
    decide(table, {"pick": np.ones(100), "behind": np.r_[np.zeros(10), np.ones(90)]}, "pick")
    assert table[1]["difference"] < 0 and table[1]["queries_needed_observed"] is None


def test_fewer_queries_than_a_switch_needs_warn_and_one_query_names_the_fix(route, few_candidates) -> None:
    X, Q = route
    with pytest.warns(UserWarning, match=f"needs at least {MIN_SWITCH_QUERIES}"):
        model = make_method("auto", budget=800).fit(X, calibration=(Q[:3], np.arange(3)))
    assert not model.choice_["calibration"]["switched"]
    with warnings.catch_warnings():  # enough queries: not this warning (at 800 B, scores near chance may be)
        warnings.filterwarnings("error", message=".*needs at least")
        make_method("auto", budget=800).fit(X, calibration=(Q[:MIN_SWITCH_QUERIES], np.arange(MIN_SWITCH_QUERIES)))
    with pytest.raises(InvalidParameterError, match="Give more"):
        make_method("auto", budget=800).fit(X, calibration=(Q[:1], np.arange(1)))


def test_a_tolerance_with_positives_is_said_to_be_unused(route, few_candidates) -> None:
    X, Q = route
    gt = GroundTruth.from_positives([[j, j + 1] for j in range(0, 100, 2)], n_map=120)
    with pytest.warns(UserWarning, match="calibration_tolerance=2 is not used"):
        model = make_method("auto", budget=800, calibration_tolerance=2).fit(X, calibration=(Q[:100:2], gt))
    c = model.choice_["calibration"]
    assert c["correct_when"] == "among the query's positives"
    assert "correct when among the query's positives" in model.summary()


@pytest.mark.parametrize("truth, where", [(np.r_[-1, np.arange(1, 10)], "query 0 has -1"),
                                          (np.r_[np.arange(9), 120], "query 9 has 120")])
def test_a_truth_outside_the_map_names_the_query(route, truth, where) -> None:
    X, Q = route
    with pytest.raises(InvalidParameterError, match=where):
        make_method("auto", budget=800).fit(X, calibration=(Q[:10], truth))


def test_a_budget_no_candidate_fits_is_refused_before_any_candidate_is_scored(route, monkeypatch) -> None:
    import btel.methods.auto.calibrate as cal

    def never(*args, **kwargs):
        raise AssertionError("calibration ran on a budget nothing fits")

    monkeypatch.setattr(cal, "choose_calibrated", never)
    X, Q = route
    with pytest.raises(BudgetTooSmallError, match=r"Raise the budget to at least \d+ B\.$"):
        make_method("auto", budget=20).fit(X, calibration=(Q[:10], np.arange(10)))


def test_progress_is_a_runtime_parameter_not_saved(route, few_candidates, tmp_path) -> None:
    X, Q = route
    model = make_method("auto", budget=800, progress=False).fit(X, calibration=(Q[:20], np.arange(20)))
    path = model.save(tmp_path / "m.btel.npz")
    assert btel.load(path).progress is True  # the default: a runtime flag is never read from a file


def test_cli_train_utm_takes_a_radius_and_says_the_ground_truth(tmp_path, few_candidates) -> None:
    rng = np.random.default_rng(0)
    X = rng.normal(size=(12, 8)).astype(np.float32)
    Q = X + 0.05 * rng.normal(size=X.shape).astype(np.float32)
    names = [f"@{543000 + 10 * i:010.2f}@4178900.00@10@S@.jpg" for i in range(12)]
    np.save(tmp_path / "db.npy", X)
    np.save(tmp_path / "q.npy", Q)
    import json

    for stem in ("db", "q"):  # the sidecar `btel extract` writes: (name, size, mtime) per row
        (tmp_path / f"{stem}.npy.json").write_text(json.dumps({"images": [[n, 0, 0] for n in names]}))
    run = CliRunner()
    base = ["train", str(tmp_path / "db.npy"), "-o", str(tmp_path / "m.npz"), "--budget", "400B", "--calibrate",
            str(tmp_path / "q.npy")]
    done = run.invoke(main, [*base, "--calibrate-truth", "utm", "--positive-dist-threshold", "5"])
    assert done.exit_code == 0, done.output
    assert "ground truth: UTM in image names, positives within 5 m" in done.stderr
    assert "correct when among the query's positives" in done.stdout
    refused = run.invoke(main, [*base, "--overwrite", "--positive-dist-threshold", "5"])
    assert refused.exit_code == 2 and "--calibrate-truth utm" in refused.output


def test_cli_train_says_the_frame_aligned_default(tmp_path, few_candidates) -> None:
    r = synthetic_route(60, 8, seed=1)
    np.save(tmp_path / "db.npy", r.map)
    np.save(tmp_path / "q.npy", r.queries[:30])
    done = CliRunner().invoke(main, ["train", str(tmp_path / "db.npy"), "-o", str(tmp_path / "m.npz"), "--budget",
                                     "400B", "--calibrate", str(tmp_path / "q.npy"), "--no-progress"])
    assert done.exit_code == 0, done.output
    assert "calibrating auto on 30 labelled queries" in done.stderr
    assert "frame-aligned (query j is place j)" in done.stderr
    assert "Traceback" not in done.output


def test_a_tolerance_spanning_the_whole_map_warns(route, few_candidates) -> None:
    X, Q = route
    with pytest.warns(UserWarning, match="spans the whole map"):
        model = make_method("auto", budget=800, calibration_tolerance=200).fit(X, calibration=(Q[:20], np.arange(20)))
    assert all(e.get("score") in (None, 1.0) for e in model.choice_["calibration"]["table"])


@pytest.mark.parametrize("command", ["train", "evaluate"])
def test_cli_an_empty_calibration_file_is_named_by_its_role(tmp_path, command) -> None:
    r = synthetic_route(40, 8, seed=2)
    np.save(tmp_path / "db.npy", r.map)
    np.save(tmp_path / "q.npy", r.queries)
    np.save(tmp_path / "none.npy", r.queries[:0])
    args = (["train", str(tmp_path / "db.npy"), "-o", str(tmp_path / "m.npz")] if command == "train" else
            ["evaluate", "--db", str(tmp_path / "db.npy"), "--queries", str(tmp_path / "q.npy"), "--methods", "auto",
             "--out", str(tmp_path / "run")])
    done = CliRunner().invoke(main, [*args, "--budget", "400B", "--calibrate", str(tmp_path / "none.npy")])
    assert done.exit_code == 2, done.output
    assert "calibration queries: descriptors in none.npy has shape (0, 8)" in done.output
    assert "Traceback" not in done.output
