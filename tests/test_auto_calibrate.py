"""Calibrated auto (btel.methods.auto.calibrate): paired, noise-aware choice; no query in the model."""

from __future__ import annotations

import json

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import btel
from btel.datasets import GroundTruth, synthetic_route
from btel.exceptions import DimensionMismatchError, InvalidDescriptorsError, InvalidParameterError
from btel.methods import make_method
from btel.methods.auto.calibrate import (
    ALPHA,
    CANDIDATES,
    SEEDS,
    compared_rows,
    decide,
    max_t_pvalues,
    mcnemar_exact,
    queries_needed,
)


@pytest.fixture(scope="module")
def route():
    r = synthetic_route(240, 24, condition_shift=1.5, noise=0.4, seed=5)
    return r.map, r.queries


@pytest.fixture(scope="module")
def calibrated(route):
    X, Q = route
    model = make_method("auto", budget=1_500, calibration_tolerance=1)
    return model.fit(X, calibration=(Q[::2], np.arange(240)[::2]))


def _table(correct: dict[str, np.ndarray]) -> list[dict]:
    return [{"candidate": k, "status": "ok", "score": float(v.mean())} for k, v in correct.items()]


def test_the_table_holds_every_candidate_scored_on_the_same_queries(calibrated) -> None:
    c = calibrated.choice_["calibration"]
    assert [e["candidate"] for e in c["table"]][: len(CANDIDATES)] == [
        label for label, *_ in CANDIDATES
    ] or c["table"][0]["candidate"] == "map-only pick"
    assert c["n_queries"] == 120 and c["tolerance"] == 1 and c["seeds"] == list(SEEDS)
    scored = [e for e in c["table"] if e["status"] == "ok"]
    assert len(scored) >= 8
    pick = next(e for e in scored if e["candidate"] == c["map_only"])
    for e in scored:
        if e is not pick:  # paired against the map-only pick on the same 120 queries
            assert e["difference"] == pytest.approx(e["score"] - pick["score"], abs=1e-3)
            assert e["wins"] + e["losses"] <= 120 and 0 <= e["p_adjusted"] <= 1
            assert e["confidence"] == pytest.approx(1 - e["p_adjusted"], abs=1e-4)
    unfit = [e for e in c["table"] if e["status"] != "ok"]
    assert all(e["status"] == "over budget" and e["needs"].endswith("B") for e in unfit)
    assert c["chosen"] in calibrated.summary() and "n for 0.05" in calibrated.summary()
    # The power column speaks of leads: a candidate behind the pick gets none (it read "3007 queries
    # would certify a lead of 0.05" beside a candidate 0.46 behind).
    header = next(line for line in calibrated.summary().splitlines() if "n for 0.05" in line and "candidate" in line)
    column = slice(header.index("n for 0.05"), header.index("n for 0.05") + len("n for 0.05"))
    behind = [e for e in scored if e is not pick and e["difference"] < 0 and e.get("queries_needed")]
    assert behind, "the fixture should have a candidate behind the pick with a power figure"
    for e in behind:
        row = next(line for line in calibrated.summary().splitlines() if line.startswith(f"  {e['candidate']:<28} "))
        assert row[column].strip() == "", row


def test_the_model_file_holds_no_calibration_query(calibrated, route, tmp_path) -> None:
    """Every stored array and the header: no query row, no array with a row per calibration query."""
    X, Q = route
    path = calibrated.save(tmp_path / "cal.btel.npz")
    from btel.core.modelfile import HEADER_KEY

    with np.load(path, allow_pickle=False) as z:
        arrays = {k: z[k] for k in z.files}
    text = arrays.pop(HEADER_KEY).tobytes().decode()
    assert arrays
    for name, a in arrays.items():
        assert 120 not in a.shape and 240 not in a.shape[1:], (name, a.shape)
        if a.ndim == 2 and a.shape[1] == Q.shape[1]:
            near = np.abs(a.astype(np.float32)[:, None, :] - Q[None, ::2]).max(axis=2)
            assert near.min() > 1e-3, name
    assert "calibration" in text

    # The header holds scalars only: no list as long as the calibration set.
    def lists(node):
        if isinstance(node, dict):
            for v in node.values():
                yield from lists(v)
        elif isinstance(node, list):
            yield node
            for v in node:
                yield from lists(v)

    parsed = json.loads(text)
    assert all(len(x) < 120 for x in lists(parsed))
    again = btel.load(path)
    assert again.choice_["calibration"] == calibrated.choice_["calibration"]
    assert again.summary() == calibrated.summary()
    np.testing.assert_array_equal(again.predict(Q), calibrated.predict(Q))


def test_a_clear_winner_is_taken_and_a_difference_within_noise_is_not() -> None:
    rng = np.random.default_rng(0)
    base = (rng.random(200) < 0.4).astype(float)
    clear = np.maximum(base, rng.random(200) < 0.5)  # right wherever the pick is, and on ≈ 30 % more
    slight = base.copy()
    slight[np.flatnonzero(base == 0)[:4]] = 1  # 4 queries of 200 better
    table = _table({"pick": base, "clear": clear, "slight": slight})
    assert decide(table, {"pick": base, "clear": clear, "slight": slight}, "pick") == "clear"
    table = _table({"pick": base, "slight": slight})
    assert decide(table, {"pick": base, "slight": slight}, "pick") == "pick"
    entry = next(e for e in table if e["candidate"] == "slight")
    assert entry["wins"] == 4 and entry["losses"] == 0 and entry["p_adjusted"] >= ALPHA
    assert entry["role"] == "" and next(e for e in table if e["candidate"] == "pick")["role"] == "chosen"


def test_wins_and_losses_count_queries_by_seed_averaged_correctness_as_the_legend_says() -> None:
    """With two seeds a query's correctness is 0, 0.5 or 1: W/L count the queries a candidate gets right
    more often / less often than the pick, so 14/14 can go with a negative diff (a user read it as a
    contradiction of a legend that spoke of right and wrong)."""
    from btel.methods.auto.localizer import CALIBRATION_COLUMNS

    pick = np.array([1.0, 1.0, 0.5, 0.0, 0.5])
    candidate = np.array([0.5, 0.0, 1.0, 0.5, 0.5])
    table = _table({"pick": pick, "candidate": candidate})
    decide(table, {"pick": pick, "candidate": candidate}, "pick")
    entry = next(e for e in table if e["candidate"] == "candidate")
    assert (entry["wins"], entry["losses"]) == (2, 2) and entry["difference"] == pytest.approx(-0.1)
    legend = " ".join(CALIBRATION_COLUMNS.split())
    assert "W/L: queries it gets right more often than the pick / less often (over the seeds)" in legend


@settings(max_examples=5, deadline=None)
@given(st.integers(0, 2**31 - 1))
def test_under_the_null_the_family_wise_switch_rate_is_near_alpha(seed: int) -> None:
    """Ten correlated candidates no better than the pick (each query's difference symmetric): max-T
    switches in about α of the trials (a binomial bound over 120 trials)."""
    rng = np.random.default_rng(seed)
    switches = 0
    for _ in range(120):
        shared = rng.random(100) < 0.5  # correlated candidates, as real ones are
        diffs = np.where(
            rng.random((10, 100)) < 0.3, np.where(shared, 1.0, -1.0) * rng.choice([-1, 1], (10, 1)), 0.0
        ) * rng.choice([-1.0, 1.0], size=(10, 100))
        switches += bool(
            (
                max_t_pvalues(diffs, n_boot=400, seed=int(rng.integers(1 << 30)))[diffs.mean(axis=1) > 0]
                < ALPHA
            ).any()
        )
    assert switches <= 16  # P(Binomial(120, 0.05) > 16) < 0.001


def test_mcnemar_and_queries_needed_match_their_formulas() -> None:
    assert mcnemar_exact(0, 0) == 1.0
    assert mcnemar_exact(10, 0) == pytest.approx(0.5**10)
    assert mcnemar_exact(6, 4) == pytest.approx(
        sum(__import__("math").comb(10, k) for k in range(6, 11)) / 1024
    )
    # Connor (1987): ψ = 0.2, δ = 0.05, one-sided α = 0.05, power 0.8:
    # (1.645·√0.2 + 0.842·√0.1975)² / 0.0025.
    assert queries_needed(0.2, 0.05, 0.05) == int(
        np.ceil((1.6449 * 0.2**0.5 + 0.8416 * 0.1975**0.5) ** 2 / 0.0025)
    )
    assert queries_needed(0.001, 0.05) is None
    assert compared_rows(256) == 4096 and compared_rows(8192) == 2048 and compared_rows(10**6) == 256


@pytest.mark.parametrize(
    "calibration, error",
    [
        (np.zeros((3, 24), dtype=np.float32), InvalidParameterError),  # not a pair
        ((np.zeros((3, 23), dtype=np.float32), np.arange(3)), DimensionMismatchError),
        ((np.full((3, 24), np.nan, dtype=np.float32), np.arange(3)), InvalidDescriptorsError),
        (
            (np.ones((3, 24), dtype=np.float32), np.arange(4)),
            InvalidParameterError,
        ),  # truth of the wrong length
        (
            (np.ones((3, 24), dtype=np.float32), np.array([0, 1, 240])),
            InvalidParameterError,
        ),  # outside the map
        ((np.ones((3, 24), dtype=np.float32), np.array([0.0, 1.0, 2.0])), InvalidParameterError),
        ((np.ones((1, 24), dtype=np.float32), np.arange(1)), InvalidParameterError),  # one query
        (
            (np.ones((3, 24), dtype=np.float32), GroundTruth.from_places([0, 1], n_map=240)),
            InvalidParameterError,
        ),
    ],
)
def test_bad_calibration_input_is_refused_naming_the_problem(route, calibration, error) -> None:
    X, _ = route
    with pytest.raises(error):
        make_method("auto", budget=1_500).fit(X, calibration=calibration)


@pytest.fixture
def few_candidates(monkeypatch):
    """Three candidates (the mechanism, not the candidate list, is under test): fast fits."""
    import btel.methods.auto.calibrate as cal

    monkeypatch.setattr(
        cal,
        "CANDIDATES",
        tuple(c for c in CANDIDATES if c[0] in ("lsh", "lsh centred", "btel-codes periodic")),
    )


def test_ground_truth_positives_calibrate_like_true_places(route, few_candidates) -> None:
    X, Q = route
    truth = np.arange(240)[1::2]
    gt = GroundTruth.from_positives([np.arange(max(0, t - 1), min(240, t + 2)) for t in truth], n_map=240)
    a = make_method("auto", budget=1_500, calibration_tolerance=1).fit(X, calibration=(Q[1::2], truth))
    b = make_method("auto", budget=1_500).fit(X, calibration=(Q[1::2], gt))
    scores = lambda m: [e.get("score") for e in m.choice_["calibration"]["table"]]  # noqa: E731
    assert scores(a) == scores(b) and a.choice_["method"] == b.choice_["method"]


def test_a_large_map_is_compared_on_a_subsample_and_the_winner_refitted_whole(
    few_candidates, monkeypatch
) -> None:
    import btel.methods.auto.calibrate as cal

    monkeypatch.setattr(cal, "MAX_ROWS", 128)  # the cap under test, at a size that fits quickly
    rng = np.random.default_rng(1)
    n, d = 700, 32
    X = rng.normal(size=(n, d)).astype(np.float32)
    Q = X[::7] + 0.3 * rng.normal(size=(100, d)).astype(np.float32)
    model = make_method("auto", budget=n * 64).fit(X, calibration=(Q, np.arange(0, n, 7)))
    c = model.choice_["calibration"]
    # Half the compared places are the queries' true places (50 of the 100), the rest evenly spaced.
    assert c["rows_compared"] == 128 and c["budget_compared"] == 128 * 64
    assert model.n_places_ == n and model.nbytes <= n * 64
    assert (model.predict(Q) == np.arange(0, n, 7)).mean() > 0.5


@pytest.mark.realdata
def test_gardens_point_mapped_at_night_calibration_scores_every_candidate_paired(
    gardenspoint_netvlad,
) -> None:
    """The map-only rule's weak spot: the calibration table on the night map, day queries (even ones)."""
    day, night = gardenspoint_netvlad
    model = make_method("auto", budget="4KB", calibration_tolerance=2).fit(
        night, calibration=(day[::2], np.arange(200)[::2])
    )
    c = model.choice_["calibration"]
    assert c["map_only"] == "btel-codes periodic" and c["n_queries"] == 100
    scored = {e["candidate"]: e for e in c["table"] if e["status"] == "ok"}
    assert {"lsh", "lsh centred", "lsh shrink", "btel-codes periodic", "rabitq"} <= set(scored)
    odd = np.arange(200)[1::2]
    chosen = scored[c["chosen"]]
    recall = np.mean(np.abs(model.predict(day[1::2]) - odd) <= 2)
    if c["switched"]:
        assert chosen["p_adjusted"] < ALPHA and chosen["difference"] > 0
    # Whatever it chose, the held-out (odd) queries agree with the calibration within noise.
    assert abs(recall - chosen["score"]) < 0.15


@pytest.mark.realdata
def test_cli_train_calibrate_on_the_gardens_point_sample_writes_the_table_and_no_query(
    gardenspoint_sample_dir, tmp_path
) -> None:
    from click.testing import CliRunner

    from btel.cli import main
    from btel.core.modelfile import HEADER_KEY

    run = CliRunner()
    for part in ("ref", "query"):
        done = run.invoke(
            main,
            [
                "extract",
                str(gardenspoint_sample_dir / part),
                "-o",
                str(tmp_path / f"{part}.npy"),
                "--no-progress",
            ],
        )
        assert done.exit_code == 0, done.output
    model = tmp_path / "m.npz"
    done = run.invoke(
        main,
        [
            "train",
            str(tmp_path / "ref.npy"),
            "-o",
            str(model),
            "--budget",
            "4KB",
            "--calibrate",
            str(tmp_path / "query.npy"),
            "--calibrate-tolerance",
            "1",
        ],
    )
    assert done.exit_code == 0, done.output
    info = run.invoke(main, ["info", str(model)])
    assert info.exit_code == 0 and "calibration: 10 labelled queries, correct when within 1 place of the true place" in info.output
    assert "btel-codes periodic" in info.output and "map-only pick" in info.output
    Q = np.load(tmp_path / "query.npy")
    with np.load(model, allow_pickle=False) as z:
        stored = {k: z[k] for k in z.files if k != HEADER_KEY}
    assert not any(a.ndim == 2 and a.shape[1] == Q.shape[1] for a in stored.values())  # no descriptor rows
    assert sum(a.nbytes for a in stored.values()) <= 4_000 < Q[0].nbytes  # less than one query descriptor


@pytest.mark.parametrize(
    "args, message",
    [
        (["--method", "lsh", "--calibrate", "q.npy"], "Use --method auto"),
        (["--calibrate-truth", "gt.npy"], "--calibrate-truth applies with --calibrate QUERIES"),
    ],
)
def test_cli_train_refuses_calibration_options_without_auto_or_queries(args, message, tmp_path) -> None:
    from click.testing import CliRunner

    from btel.cli import main

    np.save(tmp_path / "db.npy", np.ones((4, 3), dtype=np.float32))
    done = CliRunner().invoke(main, ["train", str(tmp_path / "db.npy"), "-o", str(tmp_path / "m.npz"), *args])
    assert done.exit_code == 2 and message in done.output


@pytest.mark.parametrize("d", [64, 1024, 1025, 16_384])
def test_opq_is_a_candidate_up_to_its_width_bound_and_rabitq_at_every_width(d) -> None:
    """OPQ learns a d × d rotation (O(d³)); RaBitQ's seeded rotation is O(d log d), so it stays."""
    from btel.methods.auto.calibrate import MAX_ROTATION_FEATURES, calibration_candidates

    methods = {c["method"] for c in calibration_candidates(n_features=d)}
    assert "rabitq" in methods
    assert ("opq" in methods) == (d <= MAX_ROTATION_FEATURES)


def test_a_ground_truth_no_candidate_beats_chance_on_is_warned_of() -> None:
    """Queries 0, 2, 4, … labelled as places 0, 1, 2, … (the truth of another split) gave a table of
    scores near 0 without a word; the right truth is not warned of."""
    import warnings

    route = synthetic_route(300, 32, seed=0)
    queries = route.queries[::2]
    with pytest.warns(UserWarning, match="random guesses reach by luck"):
        make_method("auto", budget="4KB").fit(route.map, calibration=(queries, np.arange(150)))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        make_method("auto", budget="4KB").fit(route.map, calibration=(queries, np.arange(0, 300, 2)))


def test_calibration_candidates_fit_without_warnings_about_their_own_codes() -> None:
    """A PQ candidate at 3 KB on 300 rows of d = 256 gets codes of fewer than log2 N bits: fitted directly it
    warns (CollidingCodesWarning); as one of calibration's candidates it is scored without a word, by an
    attribute of the candidate rather than a process-wide warnings filter (threaded fits share those)."""
    import warnings

    from btel.exceptions import CollidingCodesWarning

    route = synthetic_route(300, 256, seed=1)
    with pytest.warns(CollidingCodesWarning):
        btel.make_method("pq", budget=3000).fit(route.map)
    with warnings.catch_warnings():
        warnings.simplefilter("error", CollidingCodesWarning)
        model = btel.make_method("auto", budget=3000, calibration_tolerance=2).fit(
            route.map, calibration=(route.queries[::3], np.arange(0, 300, 3)))
    pq = [e for e in model.choice_["calibration"]["table"] if e["candidate"] == "pq"]
    assert pq and pq[0]["status"] == "ok" and "score" in pq[0], pq
