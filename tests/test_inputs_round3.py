"""A newcomer's mix-ups, named for what they are (issue round 3): a model where descriptors go, a
descriptor matrix where a model goes (`btel info`), the JSON record beside an extracted matrix, and a
.npy, .npz or .h5 piped into `btel localize --stream`."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from btel.cli import main


def _invoke(*args: object):  # noqa: ANN202
    return CliRunner().invoke(main, [str(a) for a in args])


@pytest.fixture()
def small(bruteforce_files) -> tuple[Path, Path, Path]:
    """A 40-place map of 12-value descriptors, noisy queries, and a brute-force model of the map."""
    return bruteforce_files(40, 12, "m.btel.npz")


def test_a_model_given_where_descriptors_go_is_named_with_where_it_goes(small, tmp_path: Path) -> None:
    """It was "holds 5 arrays (__btel_header__, …); choose one: m.btel.npz:__btel_header__"."""
    db, q, model = small
    for args in (["train", model, "-o", tmp_path / "x.npz"], ["localize", model, model, "-o", tmp_path / "p.csv"],
                 ["evaluate", "--db", model, "--queries", q, "--methods", "bruteforce", "--out", tmp_path / "r"]):
        result = _invoke(*args)
        assert result.exit_code == 2, result.output
        assert "is a btel model file (written by `btel train` or model.save), not descriptors" in result.output
        assert f"btel localize {model} QUERIES" in result.output and "__btel_header__" not in result.output


def test_btel_info_names_a_descriptor_matrix_instead_of_calling_it_corrupt(small) -> None:
    db, _, model = small
    result = _invoke("info", db)
    assert result.exit_code == 2 and "corrupt" not in result.output
    assert f"MODEL {db} looks like a descriptor matrix (40 × 12 float32), not a model" in result.output
    assert "usage: btel info MODEL" in result.output and f"btel train {db} -o model.npz" in result.output
    assert _invoke("info", model).exit_code == 0


def test_the_train_command_suggested_for_an_npz_of_several_arrays_names_one_and_runs(small, tmp_path: Path) -> None:
    """For an .npz holding a map and queries, `btel info` suggested `btel train FILE.npz -o model.npz`, which
    then failed asking for FILE.npz:KEY."""
    db, q, _ = small
    both = tmp_path / "both.npz"
    np.savez(both, hlrTrain=np.load(db), hlrTest=np.load(q))
    result = _invoke("info", both)
    assert result.exit_code == 2
    assert f"btel train {both}:hlrTrain -o model.npz (it holds hlrTrain, hlrTest" in result.output
    assert _invoke("train", f"{both}:hlrTrain", "-o", tmp_path / "model.npz").exit_code == 0


def test_the_json_record_beside_an_extracted_matrix_points_to_the_matrix(small, tmp_path: Path) -> None:
    db, _, _ = small
    record = db.with_name(db.name + ".json")
    record.write_text(json.dumps({"descriptor": "hog", "images": ["a.png"]}))
    result = _invoke("train", record, "-o", tmp_path / "x.npz")
    assert result.exit_code == 2 and "np.loadtxt" not in result.output
    assert f"is a JSON document (such as the record `btel extract` writes beside its .npy)" in result.output
    assert f"it describes {str(db)!r}, the matrix to give here" in result.output
    other = tmp_path / "settings.json"
    other.write_text('{"a": 1}\n')
    result = _invoke("train", other, "-o", tmp_path / "x.npz")
    assert result.exit_code == 2 and "JSON document" in result.output and "it describes" not in result.output


@pytest.mark.parametrize("kind, named", [("npy", "a .npy file"), ("npz", "a zip archive"), ("h5", "an HDF5 file")])
def test_a_binary_file_piped_into_the_stream_stops_it_with_one_error(small, tmp_path: Path, kind: str,
                                                                      named: str) -> None:
    """It was one "binary data …" error per line (96,165 of them for a Nordland map) and exit 0."""
    db, q, model = small
    source = {"npy": q, "npz": model, "h5": tmp_path / "q.h5"}[kind]
    if kind == "h5":
        import h5py

        with h5py.File(source, "w") as fh:
            fh["q"] = np.load(q)
    run = subprocess.run([sys.executable, "-m", "btel.cli", "localize", str(model), "--stream"],
                         stdin=source.open("rb"), capture_output=True, text=True, timeout=120)
    assert run.returncode == 2, run.stderr
    assert f"the input is {named}" in run.stderr and "btel localize MODEL QUERIES -o predictions.csv" in run.stderr
    assert run.stderr.count("\n") <= 3 and run.stdout == ""


def test_a_text_stream_is_not_mistaken_for_a_file_format(small) -> None:
    """The check reads the first line only, and only for a binary file's first bytes."""
    db, q, model = small
    lines = "\n".join(",".join(f"{v:.6g}" for v in row) for row in np.load(q)[:5]) + "\n"
    result = CliRunner().invoke(main, ["localize", str(model), "--stream"], input=lines)
    assert result.exit_code == 0, result.output
    assert result.output.split() == ["0", "1", "2", "3", "4"]


def test_btel_report_on_an_evaluate_run_says_its_tables_are_already_there(small, tmp_path: Path) -> None:
    """It said "no experiment results …; run `btel experiment all` first" to a user with a finished run."""
    db, q, _ = small
    run = tmp_path / "runs" / "mine"
    assert _invoke("evaluate", "--db", db, "--queries", q, "--methods", "bruteforce", "--out", run).exit_code == 0
    result = _invoke("report", "--runs", run, "--docs", tmp_path / "docs")
    assert result.exit_code == 2, result.output
    assert f"is a `btel evaluate` run: its tables (metrics.json, the CSV files) and plots are already in that folder" \
        in " ".join(result.output.split())
    assert not (tmp_path / "docs").exists()


def test_a_saved_descriptor_asking_for_huge_rows_is_refused_from_its_shapes(tmp_path: Path) -> None:
    """594 bytes asking for 48,000 HOG orientations took 4.9 GB over 30 small images (80 MB an image, a
    256-row batch buffer filled as it went); now the rows' bytes are checked before an image is read."""
    import cv2

    from btel.descriptors.hog import HOGDescriptor

    HOGDescriptor(orientations=48_000).save(tmp_path / "hog_big.btel.npz")
    folder = tmp_path / "imgs"
    folder.mkdir()
    for i in range(8):  # 8 × 80 MB: over the 256 MiB default
        cv2.imwrite(str(folder / f"{i}.png"), np.full((32, 64), 20 * i, np.uint8))
    result = _invoke("extract", folder, "-o", tmp_path / "x.npy", "--descriptor", tmp_path / "hog_big.btel.npz")
    assert result.exit_code == 2, result.output
    assert "8 hog descriptors of 20160000 values would need" in result.output and "BTEL_MEMORY_LIMIT" in result.output
    assert not (tmp_path / "x.npy").exists()
    assert _invoke("extract", folder, "-o", tmp_path / "ok.npy", "--descriptor", "hog").exit_code == 0
