"""VPR-methods-evaluation conventions (btel.datasets.vpr_names) and their use by `btel evaluate`."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from btel.cli import main
from btel.datasets.vpr_names import split_dataset_folder, utm_from_name, utm_of_names
from btel.methods import METHODS
from btel.exceptions import InvalidParameterError


def test_utm_from_names() -> None:
    assert utm_from_name("@0543256.96@4178906.70@10@S@037.75643@-122.50411@@@@@@@@.jpg") == (543256.96, 4178906.70)
    assert utm_from_name("queries/@1@2@x.jpg") == (1.0, 2.0)  # the folder is not part of the name
    for bad in ("0.jpg", "@east@north@.jpg", "@1.0.jpg"):
        with pytest.raises(InvalidParameterError, match="@utm_east@utm_north@"):
            utm_from_name(bad)
    with pytest.raises(InvalidParameterError, match="--db x"):
        utm_of_names(["@1@2@a.jpg", "b.jpg"], "--db x")


def test_split_dataset_folder(tmp_path: Path) -> None:
    assert split_dataset_folder(tmp_path) is None
    (tmp_path / "database").mkdir()
    (tmp_path / "queries").mkdir()
    assert split_dataset_folder(tmp_path) == (tmp_path / "database", tmp_path / "queries")


@pytest.mark.realdata
def test_vpr_methods_evaluation_folder_end_to_end(gardenspoint_sample_dir: Path, tmp_path: Path) -> None:
    """Gardens Point frames renamed the VPR-methods-evaluation way (place i at 10·i m east): extract,
    evaluate with UTM positives within 25 m (±2 places), and an hloc pairs file with the image names."""
    data = tmp_path / "gp"
    for sub, src, north in (("database", "ref", 0.0), ("queries", "query", 3.0)):
        (data / sub).mkdir(parents=True)
        for image in sorted((gardenspoint_sample_dir / src).glob("*.jpg")):
            i = int(image.stem)
            (data / sub / f"@{500000 + 10 * i:.2f}@{4000000 + north:.2f}@55@H@@.jpg").symlink_to(image)
    runner = CliRunner()
    refused = runner.invoke(main, ["extract", str(data), "-o", str(tmp_path / "x.npy")])
    assert refused.exit_code == 2 and "database/ and queries/" in refused.output
    db, q = tmp_path / "db.npy", tmp_path / "q.npy"
    for sub, out in (("database", db), ("queries", q)):
        result = runner.invoke(main, ["extract", str(data / sub), "-o", str(out), "--descriptor", "patchnorm",
                                      "--size", "56x32", "--no-progress"])
        assert result.exit_code == 0, result.output
    pairs, out = tmp_path / "pairs.txt", tmp_path / "run"
    args = ["evaluate", "--db", str(db), "--queries", str(q), "--methods", "bruteforce", "--ground-truth", "utm",
            "--query-order", "independent", "--pairs", str(pairs), "--no-progress", "--out", str(out)]
    result = runner.invoke(main, args)
    assert result.exit_code == 0, result.output
    assert "positives within 25 m" in result.output and "R@20" not in result.output  # 10 places: K ≤ N
    lines = pairs.read_text().splitlines()
    n = len(list((data / "queries").iterdir()))
    assert len(lines) == n * min(10, n)
    query, best = lines[0].split(" ")
    assert query.startswith("@") and query.endswith(".jpg") and best.startswith("@5000")
    # R@1 recomputed from the pairs file: the best match within 25 m of the query.
    hits = [abs(utm_from_name(a)[0] - utm_from_name(b)[0]) <= 25 for a, b in (line.split() for line in lines[::min(10, n)])]
    import json

    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["results"][0]["recall_at_k"]["1"] == pytest.approx(np.mean(hits))
    # The pairs file is not replaced silently, and the threshold only goes with utm.
    again = runner.invoke(main, [*args[:-1], str(tmp_path / "run2")])
    assert again.exit_code == 2 and "--pairs" in again.output and "already exists" in again.output
    wrong = runner.invoke(main, ["evaluate", "--db", str(db), "--queries", str(q), "--positive-dist-threshold", "10",
                                 "--out", str(tmp_path / "run3")])
    assert wrong.exit_code == 2 and "--ground-truth utm" in wrong.output
    # The run describes itself: what auto chose and why, and the ground truth's source and 25 m rule.
    result = runner.invoke(main, ["evaluate", "--db", str(db), "--queries", str(q), "--ground-truth", "utm",
                                  "--budget", "64KB", "--query-order", "independent", "--no-progress",
                                  "--out", str(tmp_path / "auto")])
    assert result.exit_code == 0, result.output
    metrics = json.loads((tmp_path / "auto" / "metrics.json").read_text())
    auto = next(r for r in metrics["results"] if r["name"] == "auto")
    assert auto["choice"]["method"] in METHODS and auto["choice"]["reason"] and "params" in auto["choice"]
    for row in metrics["results"]:
        assert row["ground_truth_source"] == "UTM in image names"
        assert row["positive_rule"] == "positives within 25 m"
    assert metrics["run"]["extra"]["ground_truth"] == {"source": "UTM in image names",
                                                       "rule": "positives within 25 m"}
    assert {r["name"]: r["choice"] for r in metrics["results"]}["bruteforce"] is None
    assert (tmp_path / "auto" / "predictions_bruteforce-shrink.csv").is_file()


# -- issue 34, item 3: names become structure -----------------------------------------------------------
from btel.datasets.vpr_names import check_image_names  # noqa: E402


@pytest.mark.parametrize("name, space, file_name, message", [
    ("db/a\nINJECTED db/evil", True, False, r"'db/a\\nINJECTED db/evil' \(row 1\) holds U\+000A"),
    ("db/c d", False, False, r"'db/c d' \(row 1\) holds U\+0020 \(a space\); hloc pairs files"),
    ("a\tb", True, False, r"U\+0009"),
    ("a\u2028b", True, False, r"U\+2028"),
    ("a\u202eb", True, False, r"U\+202E"),  # a right-to-left override: shown, not obeyed
    ("a\x00b", True, False, r"U\+0000"),
    ("", True, False, "row 1 is empty"),
    ("../../etc/passwd", True, True, "not a plain file name"),
    ("..", True, True, "not a plain file name"),
])
def test_names_that_would_change_a_file_are_refused_by_name(name: str, space: bool, file_name: bool,
                                                           message: str) -> None:
    with pytest.raises(InvalidParameterError, match=message):
        check_image_names(["ok.jpg", name], "--db x.h5", space=space, file_name=file_name)


def test_ordinary_names_pass() -> None:
    check_image_names(["db/0001.jpg", "queries/@0543256.96@4178906.70@10@S@.jpg", "été 1.png", "日本.png"], "x")
    check_image_names(["my photo.jpg"], "x", file_name=True)
    with pytest.raises(InvalidParameterError, match="a space"):
        check_image_names(["my photo.jpg"], "x", space=False)


def _hloc(path: Path, names: list[str]) -> Path:
    h5py = pytest.importorskip("h5py")
    rng = np.random.default_rng(0)
    with h5py.File(path, "w") as fh:
        for name in names:
            fh.create_group(name).create_dataset("global_descriptor", data=rng.normal(size=8).astype("f4"))
    return path


@pytest.mark.parametrize("bad, written", [("db/a\nINJECTED db/evil", "predictions"), ("db/c d", "pairs")])
def test_evaluate_refuses_names_that_would_break_its_files_before_fitting(tmp_path: Path, bad: str,
                                                                         written: str) -> None:
    """Issue 34: HDF5 image names such as ``db/a\\nINJECTED db/evil`` or ``db/c d`` went unescaped into
    the --pairs file: one map name wrote its own line."""
    feats = _hloc(tmp_path / "feats.h5", [bad, "db/e", "db/f", "query/q1", "query/q2"])
    out, pairs = tmp_path / "run", tmp_path / "pairs.txt"
    result = CliRunner().invoke(main, ["evaluate", "--db", f"{feats}:db/", "--queries", f"{feats}:query/",
                                       "--methods", "bruteforce", "--no-reference", "--pairs", str(pairs),
                                       "--k", "3", "--no-progress", "--out", str(out)])
    assert result.exit_code == 2 and isinstance(result.exception, SystemExit), result.output
    error = [line for line in result.output.splitlines() if line.startswith("Error:")]
    assert len(error) == 1 and repr(bad) in error[0] and "fitting" not in result.output
    assert not pairs.exists() and not out.exists()
    if written == "pairs":  # without --pairs the name is fine (the CSV quotes it): the run is written
        result = CliRunner().invoke(main, ["evaluate", "--db", f"{feats}:db/", "--queries", f"{feats}:query/",
                                           "--methods", "bruteforce", "--no-reference", "--no-progress",
                                           "--out", str(out)])
        assert result.exit_code == 0, result.output
        assert len((out / "predictions_bruteforce.csv").read_text().splitlines()) == 3


def test_a_pairs_file_holds_one_pair_per_line(tmp_path: Path) -> None:
    names = ["db/0.jpg", "db/été_1.jpg", "db/@1@2@x.jpg"]
    feats = _hloc(tmp_path / "feats.h5", names + ["query/q1.jpg", "query/q2.jpg"])
    pairs = tmp_path / "pairs.txt"
    result = CliRunner().invoke(main, ["evaluate", "--db", f"{feats}:db/", "--queries", f"{feats}:query/",
                                       "--methods", "bruteforce", "--no-reference", "--pairs", str(pairs),
                                       "--k", "3", "--no-progress", "--out", str(tmp_path / "run")])
    assert result.exit_code == 0, result.output
    lines = pairs.read_text(encoding="utf-8").split("\n")
    assert lines[-1] == "" and len(lines[:-1]) == 2 * 3
    assert all(len(line.split()) == 2 and line.split()[0].startswith("query/") for line in lines[:-1])


def test_write_pairs_checks_names_itself(tmp_path: Path) -> None:
    from btel.cli._names import write_pairs

    with pytest.raises(InvalidParameterError, match="U\\+000D"):
        write_pairs(tmp_path / "p.txt", np.array([[0]]), ["q\rx"], ["db/0.jpg"])
    assert not (tmp_path / "p.txt").exists()


def test_the_predictions_csv_refuses_a_name_that_would_take_two_lines() -> None:
    """The library's own guard (btel evaluate refuses earlier, before fitting)."""
    from btel.datasets import GroundTruth
    from btel.evaluation.records import EvaluationResult
    from btel.evaluation.tables import predictions_csv_text

    result = EvaluationResult(name="m", n_queries=2, predictions=np.array([0, 1]),
                              ground_truth=GroundTruth.frame_aligned(2))
    assert predictions_csv_text(result, ["q0", "q 1"], ["d0", "d1"]).count("\n") == 3
    with pytest.raises(InvalidParameterError, match=r"map names: image name 'd\\n1' \(row 1\)"):
        predictions_csv_text(result, ["q0", "q1"], ["d0", "d\n1"])


@pytest.mark.realdata
def test_real_descriptors_in_an_hloc_file_give_one_pair_per_line(gardenspoint_netvlad,
                                                                  tmp_path: Path) -> None:
    """Gardens Point NetVLAD written as hloc features (gzip + shuffle chunks, names with '@' and '.'):
    read back exactly, and the pairs file holds one pair per line, each query's top 5."""
    h5py = pytest.importorskip("h5py")
    from btel.descriptors.hdf5 import load_hloc_global

    db, q = gardenspoint_netvlad
    with h5py.File(tmp_path / "feats.h5", "w") as fh:
        for prefix, X in (("db", db), ("query", q)):
            for i, row in enumerate(X):
                fh.create_group(f"{prefix}/@{i}@0@gp_{i:04d}.jpg").create_dataset(
                    "global_descriptor", data=row, compression="gzip", shuffle=True)
    X, names = load_hloc_global(tmp_path / "feats.h5", "db/")
    np.testing.assert_array_equal(X, db)
    assert names[:2] == ["db/@0@0@gp_0000.jpg", "db/@1@0@gp_0001.jpg"]
    pairs = tmp_path / "pairs.txt"
    feats = tmp_path / "feats.h5"
    result = CliRunner().invoke(main, ["evaluate", "--db", f"{feats}:db/", "--queries", f"{feats}:query/",
                                       "--methods", "bruteforce", "--no-reference", "--k", "1,5", "--pairs",
                                       str(pairs), "--no-progress", "--out", str(tmp_path / "run")])
    assert result.exit_code == 0, result.output
    lines = pairs.read_text(encoding="utf-8").splitlines()
    assert len(lines) == 5 * q.shape[0] and all(len(line.split()) == 2 for line in lines)
    assert lines[0].split()[0] == "query/@0@0@gp_0000.jpg"


def test_a_pairs_file_named_like_another_format_is_refused_before_any_fit(tmp_path: Path) -> None:
    """`--pairs pr/q.npy` wrote text files named q-lsh.npy."""
    X = np.random.default_rng(0).normal(size=(30, 8)).astype(np.float32)
    np.save(tmp_path / "db.npy", X)
    result = CliRunner().invoke(main, ["evaluate", "--db", str(tmp_path / "db.npy"), "--queries", str(tmp_path / "db.npy"),
                                       "--methods", "bruteforce", "--pairs", str(tmp_path / "q.npy"), "--no-progress",
                                       "--out", str(tmp_path / "run")])
    assert result.exit_code == 2 and "--pairs" in result.output and "q.txt" in result.output
    assert not (tmp_path / "run").exists()
