"""VPR-methods-evaluation conventions (btel.datasets.vpr_names) and their use by `btel evaluate`."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from btel.cli import main
from btel.datasets.vpr_names import split_dataset_folder, utm_from_name, utm_of_names
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
