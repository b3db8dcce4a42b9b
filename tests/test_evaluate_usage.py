"""`btel evaluate` and `btel localize` options that only make sense beside others, or within the map's size:
refused (exit 2) before anything is fitted or written, with a message naming the problem and the fix;
and what a run says of its inputs (the ground truth's positive rule, --pairs without image names)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import scipy.io
from click.testing import CliRunner

from btel.cli import main
from btel.datasets import synthetic_route

N = 200


def run(*args: object) -> "click.testing.Result":  # noqa: F821
    return CliRunner().invoke(main, [str(a) for a in args], catch_exceptions=False)


@pytest.fixture()
def route_files(tmp_path: Path) -> tuple[Path, Path]:
    route = synthetic_route(n_places=N, dim=32, seed=0)
    np.save(tmp_path / "db.npy", route.map)
    np.save(tmp_path / "q.npy", route.queries)
    return tmp_path / "db.npy", tmp_path / "q.npy"


def _error(result: "click.testing.Result") -> str:  # noqa: F821
    lines = [line for line in result.output.splitlines() if line.startswith("Error:")]
    assert len(lines) == 1, result.output
    return lines[0]


# -- 1: a CSV that omits a query ---------------------------------------------------------------------------
def test_a_csv_ground_truth_omitting_a_query_names_it(route_files, tmp_path: Path) -> None:
    """It said "it is for 199 queries but there are 200": now which query, why 199, and the fix."""
    db, q = route_files
    (tmp_path / "gt.csv").write_text("query,positive\n" + "".join(f"{j},{j}\n" for j in range(N - 1)))
    result = run("evaluate", "--db", db, "--queries", q, "--ground-truth", tmp_path / "gt.csv", "--methods", "lsh",
                 "--budget", "4KB", "--out", tmp_path / "run")
    assert result.exit_code == 2
    error = _error(result)
    assert "no line for query 199 (1 of the 200 query rows)" in error and "highest query index + 1" in error
    assert "'199,'" in error and not (tmp_path / "run").exists()


# -- 2: --positive-dist-threshold without a utm ground truth ------------------------------------------------
@pytest.mark.parametrize("truth", [None, "gt.npy"])
def test_positive_dist_threshold_without_utm_is_a_usage_error(route_files, tmp_path: Path,
                                                             truth: str | None) -> None:
    """It said "--ground-truth utm reads image names from --db (give it)" though --db was given."""
    db, q = route_files
    np.save(tmp_path / "gt.npy", np.arange(N))
    given = [] if truth is None else ["--ground-truth", tmp_path / truth]
    result = run("evaluate", "--db", db, "--queries", q, *given, "--positive-dist-threshold", "25", "--methods",
                 "lsh", "--budget", "16KB", "--out", tmp_path / "run")
    assert result.exit_code == 2
    error = _error(result)
    assert "--positive-dist-threshold 25 is the radius of --ground-truth utm" in error
    assert "applies to it (and --calibrate-truth utm) only" in error
    assert "Drop --positive-dist-threshold" in error and "give it" not in error
    assert ("default ground truth is frame-aligned" if truth is None else "gives its own positives") in error
    assert not (tmp_path / "run").exists()


# -- 3: the positive rule of positions' ground truth ----------------------------------------------------------
@pytest.mark.parametrize("layout", ["npz", "mat"])
def test_a_radius_ground_truth_records_its_radius_as_the_positive_rule(route_files, tmp_path: Path,
                                                                       layout: str) -> None:
    """A positions file (utmDb, utmQ, posDistThr; or NetVLAD's dbStruct) gave "positives listed per query"."""
    db, q = route_files
    utm = np.c_[np.arange(N) * 5.0, np.zeros(N)]
    if layout == "npz":
        gt = tmp_path / "gt.npz"
        np.savez(gt, utmDb=utm, utmQ=utm + 1, posDistThr=6.0)
    else:
        gt = tmp_path / "gt.mat"
        scipy.io.savemat(gt, {"dbStruct": {"whichSet": "test", "utmDb": utm.T, "utmQ": (utm + 1).T,
                                           "numImages": N, "numQueries": N, "posDistThr": 6.0}})
    result = run("evaluate", "--db", db, "--queries", q, "--ground-truth", gt, "--methods", "lsh", "--budget",
                 "4KB", "--no-progress", "--out", tmp_path / "run")
    assert result.exit_code == 0, result.output
    rule = "positives within 6 m (posDistThr of the file)"
    assert f"ground truth: {rule}" in result.output
    rows = json.loads((tmp_path / "run" / "metrics.json").read_text())["results"]
    assert rows and {row["positive_rule"] for row in rows} == {rule}


def test_positives_from_positions_keep_their_radius() -> None:
    from btel.datasets import GroundTruth
    from btel.datasets.sources import truth_description

    utm = np.c_[np.arange(5) * 5.0, np.zeros(5)]
    gt = GroundTruth.from_utm(utm, utm + 1, 6.0)
    assert gt.radius == 6.0 and GroundTruth.from_positives([[0], [1]]).radius is None
    assert truth_description(gt, "given in Python")["rule"] == "positives within 6 m"


# -- 4: --top-k and --tolerances beyond the map ------------------------------------------------------------------
def test_a_top_k_above_the_map_is_refused(route_files, tmp_path: Path) -> None:
    """--top-k 500 on a 200-place map wrote rank_1 … rank_200 without a word."""
    db, q = route_files
    model = tmp_path / "m.btel.npz"
    assert run("train", db, "-o", model, "--method", "lsh", "--budget", "4KB").exit_code == 0
    out = tmp_path / "tk.csv"
    result = run("localize", model, q, "-o", out, "--top-k", "500")
    assert result.exit_code == 2
    assert "--top-k 500" in _error(result) and f"N = {N}" in _error(result)
    assert f"between 1 and {N}" in _error(result) and not out.exists()
    assert run("localize", model, q, "-o", out, "--top-k", str(N)).exit_code == 0


def test_a_tolerance_of_the_map_size_or_more_is_refused(route_files, tmp_path: Path) -> None:
    """--tolerances 0,3,300 printed recall@300 = 1.000 on a 200-place map, where --k 500 is refused."""
    db, q = route_files
    result = run("evaluate", "--db", db, "--queries", q, "--methods", "lsh", "--budget", "4KB", "--tolerances",
                 f"0,3,{N},300", "--out", tmp_path / "run")
    assert result.exit_code == 2
    error = _error(result)
    assert f"--tolerances {N},300" in error and f"N = {N}" in error and f"up to {N - 1}" in error
    assert not (tmp_path / "run").exists()


# -- 5: --pairs without image names ---------------------------------------------------------------------------
def test_pairs_of_inputs_without_image_names_warn_that_they_hold_row_indices(route_files, tmp_path: Path) -> None:
    db, q = route_files
    pairs = tmp_path / "p.txt"
    result = CliRunner().invoke(main, ["evaluate", "--db", str(db), "--queries", str(q), "--methods", "lsh",
                                       "--budget", "4KB", "--no-reference", "--pairs", str(pairs), "--k", "1",
                                       "--no-progress", "--out", str(tmp_path / "run")])
    assert result.exit_code == 0, result.output
    warning = result.stderr
    assert f"--queries {q} and --db {db} record no image name per row" in warning
    assert "row index" in warning and "btel extract" in warning and ".h5" in warning
    assert "Warning" not in result.stdout
    assert pairs.read_text().splitlines()[0].split()[0] == "0"


def test_pairs_of_named_inputs_do_not_warn(tmp_path: Path) -> None:
    h5py = pytest.importorskip("h5py")
    rng = np.random.default_rng(0)
    feats = tmp_path / "feats.h5"
    with h5py.File(feats, "w") as fh:
        for name in [*(f"db/{i}.jpg" for i in range(6)), *(f"query/{i}.jpg" for i in range(3))]:
            fh.create_group(name).create_dataset("global_descriptor", data=rng.normal(size=8).astype("f4"))
    result = CliRunner().invoke(main, ["evaluate", "--db", f"{feats}:db/", "--queries", f"{feats}:query/",
                                       "--methods", "bruteforce", "--no-reference", "--ground-truth",
                                       str(_places(tmp_path)), "--pairs", str(tmp_path / "p.txt"), "--k", "2",
                                       "--no-progress", "--out", str(tmp_path / "run")])
    assert result.exit_code == 0, result.output
    assert "record no image name" not in result.stderr
    assert (tmp_path / "p.txt").read_text().startswith("query/0.jpg db/")


def _places(tmp_path: Path) -> Path:
    np.save(tmp_path / "gt.npy", np.array([0, 2, 4]))
    return tmp_path / "gt.npy"


# -- 6: --delta with independent queries ----------------------------------------------------------------------
@pytest.mark.parametrize("delta", [["--delta", "3"], ["--param", "delta=3"]])
def test_delta_with_independent_queries_is_a_usage_error(route_files, tmp_path: Path, delta: list[str]) -> None:
    """Every row was refused in a run folder written anyway (exit 1)."""
    db, q = route_files
    result = run("evaluate", "--db", db, "--queries", q, "--methods", "seqslam,lsh", "--budget", "100KB",
                 "--query-order", "independent", *delta, "--out", tmp_path / "run")
    assert result.exit_code == 2
    error = _error(result)
    assert f"{' '.join(delta) if delta[0] == '--delta' else '--param delta=3'} with --query-order independent" \
        in error
    assert "query sequence" in error and "--query-order route" in error and "fitting" not in result.output
    assert not (tmp_path / "run").exists()


@pytest.mark.parametrize("flag", [["--delta", "150"], ["--param", "delta=150"]])
def test_a_delta_window_longer_than_the_traverses_is_a_usage_error_before_any_fit(route_files, tmp_path: Path,
                                                                                   flag: list[str]) -> None:
    """Every row failed with NotEnoughPlacesError and the command exited 1, although nothing could have run."""
    db, q = route_files
    out = tmp_path / "run"
    result = run("evaluate", "--db", db, "--queries", q, "--methods", "lsh", "--no-progress", "--out", out, *flag)
    assert result.exit_code == 2 and not out.exists()
    given = "--delta 150" if flag[0] == "--delta" else "--param delta=150"  # named as the user gave it
    n = np.load(db).shape[0]
    assert f"{given} needs traverses of at least 2 × 150 = 300 frames; the map has {n}" in _error(result)
