"""Hostile input, round 7: what a seventh audit found that earlier rounds missed (each reproduced first)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from btel.cli import main


def _invoke(*args: object, env: dict[str, str] | None = None) -> "click.testing.Result":  # noqa: F821
    return CliRunner().invoke(main, [str(a) for a in args], env=env)


def test_names_equal_as_numbers_sort_one_way_whatever_the_order_they_come_in(tmp_path: Path) -> None:
    """shard_1, shard_01 and shard_001 compare equal as numbers: they were read in the order the file
    system listed them, so the map's rows could change places between machines. The tie-break must not
    meet a number either: `day` against `day2` (traverse folders) raised TypeError in a first fix."""
    import itertools

    from btel.datasets.shards import list_shards
    from btel.datasets.traverses import natural_key
    from btel.descriptors.hdf5 import _natural_key as hdf5_key
    from btel.descriptors.images import _natural_key as image_key

    names = ["shard_10.npy", "shard_1.npy", "shard_2.npy", "shard_01.npy", "shard_001.npy", "shard.npy"]
    expected = ["shard.npy", "shard_001.npy", "shard_01.npy", "shard_1.npy", "shard_2.npy", "shard_10.npy"]
    for order in itertools.permutations(names):
        assert sorted(order, key=natural_key) == expected
        assert sorted(order, key=hdf5_key) == expected
        assert [p.name for p in sorted(map(Path, order), key=image_key)] == expected
    assert sorted(["day2", "day", "day10", "day01"], key=natural_key) == ["day", "day01", "day2", "day10"]
    for name in names:
        np.save(tmp_path / name, np.zeros((1, 2), dtype=np.float32))
    assert [p.name for p in list_shards(tmp_path)] == expected


def test_a_whitening_rank_the_map_cannot_give_is_named_before_the_budget(tmp_path: Path) -> None:
    """whiten=99999999999 at 100 GB said the budget was too small (the matrix it sized), not the rank."""
    np.save(tmp_path / "db.npy", np.random.default_rng(0).normal(size=(40, 16)).astype(np.float32))
    result = _invoke("train", tmp_path / "db.npy", "-o", tmp_path / "m.npz", "--method", "lsh", "--budget", "100GB",
                     "--param", "whiten=99999999999")
    assert result.exit_code != 0 and "Use whiten ≤ 16" in result.output and "too small" not in result.output


def test_a_stream_of_carriage_returns_alone_is_named(tmp_path: Path) -> None:
    """Old Mac line ends read as one line, refused as a line cut short without a word about CR."""
    import btel

    X = np.random.default_rng(0).normal(size=(20, 4)).astype(np.float32)
    btel.make_method("bruteforce").fit(X).save(tmp_path / "m.npz")
    (tmp_path / "cr.txt").write_bytes(b"\r".join(b" ".join(b"%.4f" % v for v in row) for row in X[:3]) + b"\r")
    result = _invoke("localize", tmp_path / "m.npz", "--stream", "--input", tmp_path / "cr.txt")
    assert "carriage returns" in result.output and "tr '\\r' '\\n'" in result.output
    # CRLF text whose last line lost its LF is a line cut short, not old Mac text.
    (tmp_path / "crlf.txt").write_bytes(b"\r\n".join(b" ".join(b"%.4f" % v for v in row) for row in X[:3]) + b"\r")
    result = _invoke("localize", tmp_path / "m.npz", "--stream", "--input", tmp_path / "crlf.txt")
    assert "no newline after it" in result.output and "carriage returns" not in result.output


@pytest.mark.parametrize(("args", "message"), [
    (("--seed", "-1"), "'--seed'"),
    (("--places", "1000000000"), "choose fewer places"),
    (("--timing-threads", "100000"), "this machine has"),
])
def test_demo_options_out_of_range_are_named(args, message, tmp_path: Path) -> None:
    result = _invoke("demo", *args, "--out", tmp_path / "run")
    assert result.exit_code == 2 and message in result.output and not (tmp_path / "run").exists()


@pytest.mark.parametrize("value", ["abc", "1.5", "0", "-1", "²"])
def test_a_malformed_experiment_jobs_variable_is_named_before_any_work(value: str, tmp_path: Path) -> None:
    result = _invoke("experiment", "accuracy", "--quick", "-o", tmp_path / "out", env={"BTEL_EXPERIMENT_JOBS": value})
    assert result.exit_code != 0 and "BTEL_EXPERIMENT_JOBS" in result.output and not (tmp_path / "out").exists()


def test_a_link_where_extract_writes_its_record_is_not_replaced(tmp_path: Path) -> None:
    """A link at OUTPUT.json to a valid record was replaced by a regular file without --overwrite."""
    import cv2

    images = tmp_path / "imgs"
    images.mkdir()
    for i in range(4):
        cv2.imwrite(str(images / f"{i}.png"), np.random.default_rng(i).integers(0, 255, (32, 48), dtype=np.uint8))
    done = _invoke("extract", images, "-o", tmp_path / "a.npy", "--descriptor", "patchnorm")
    assert done.exit_code == 0, done.output
    (tmp_path / "b.npy.json").symlink_to(tmp_path / "a.npy.json")
    refused = _invoke("extract", images, "-o", tmp_path / "b.npy", "--descriptor", "patchnorm")
    assert refused.exit_code != 0 and "is a link" in refused.output
    assert (tmp_path / "b.npy.json").is_symlink() and not (tmp_path / "b.npy").exists()
