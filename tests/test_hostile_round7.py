"""Hostile input, round 7: what a seventh audit found that earlier rounds missed (each reproduced first)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from btel.cli import main


def _invoke(*args: object, env: dict[str, str] | None = None) -> "click.testing.Result":  # noqa: F821
    return CliRunner().invoke(main, [str(a) for a in args], env=env)


def test_shards_named_alike_as_numbers_are_read_in_one_order_on_every_machine(tmp_path: Path) -> None:
    """shard_1, shard_01 and shard_001 compare equal as numbers: they were read in the order the file
    system listed them, so the map's rows could change places between machines."""
    from btel.datasets.shards import list_shards

    names = ["shard_10.npy", "shard_1.npy", "shard_2.npy", "shard_01.npy", "shard_001.npy"]
    for name in names:
        np.save(tmp_path / name, np.zeros((1, 2), dtype=np.float32))
    assert [p.name for p in list_shards(tmp_path)] == ["shard_001.npy", "shard_01.npy", "shard_1.npy",
                                                        "shard_2.npy", "shard_10.npy"]


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


@pytest.mark.parametrize(("args", "message"), [
    (("--seed", "-1"), "'--seed'"),
    (("--places", "1000000000"), "choose fewer places"),
    (("--timing-threads", "100000"), "this machine has"),
])
def test_demo_options_out_of_range_are_named(args, message, tmp_path: Path) -> None:
    result = _invoke("demo", *args, "--out", tmp_path / "run")
    assert result.exit_code == 2 and message in result.output and not (tmp_path / "run").exists()


@pytest.mark.parametrize("value", ["abc", "1.5", "0", "-1"])
def test_a_malformed_experiment_jobs_variable_is_named_before_any_work(value: str, tmp_path: Path) -> None:
    result = _invoke("experiment", "accuracy", "--quick", "-o", tmp_path / "out", env={"BTEL_EXPERIMENT_JOBS": value})
    assert result.exit_code != 0 and "BTEL_EXPERIMENT_JOBS" in result.output and not (tmp_path / "out").exists()
