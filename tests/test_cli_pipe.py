"""A closed stdout (``btel … | head``) ends a command quietly with 141, as SIGPIPE ends a Unix tool."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import btel

from btel.cli._errors import EXIT_BROKEN_PIPE


def test_a_reader_that_goes_away_ends_the_command_quietly(tmp_path: Path) -> None:
    np.save(tmp_path / "db.npy", np.random.default_rng(0).standard_normal((300, 32)).astype(np.float32))
    command = [sys.executable, "-m", "btel.cli", "train", str(tmp_path / "db.npy"), "-o", str(tmp_path / "m.npz"),
               "--budget", "4KB", "--no-progress"]
    process = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    process.stdout.close()  # the reader leaves before btel prints its first line
    _, stderr = process.communicate(timeout=120)
    assert process.returncode == EXIT_BROKEN_PIPE, stderr.decode()
    assert stderr.decode().strip() == ""
    # The fit is not lost with the reader: the model was saved before the first line was printed.
    assert np.array_equal(btel.load(tmp_path / "m.npz").predict(np.load(tmp_path / "db.npy")[:5]), np.arange(5))


def test_the_same_command_with_its_reader_exits_0(tmp_path: Path) -> None:
    np.save(tmp_path / "db.npy", np.random.default_rng(0).standard_normal((300, 32)).astype(np.float32))
    done = subprocess.run([sys.executable, "-m", "btel.cli", "train", str(tmp_path / "db.npy"), "-o",
                           str(tmp_path / "m.npz"), "--budget", "4KB", "--no-progress"],
                          capture_output=True, timeout=120)
    assert done.returncode == 0 and b"model written to" in done.stdout


def test_an_evaluation_whose_reader_goes_away_still_writes_its_run_folder(tmp_path: Path) -> None:
    """`btel evaluate … | head -1`: the run folder is what the command makes; it is finished, not lost."""
    import json

    from btel.datasets import synthetic_route

    route = synthetic_route(300, 32, seed=0)
    np.save(tmp_path / "db.npy", route.map)
    np.save(tmp_path / "q.npy", route.queries)
    command = [sys.executable, "-m", "btel.cli", "evaluate", "--db", str(tmp_path / "db.npy"), "--queries",
               str(tmp_path / "q.npy"), "--methods", "pq,lsh", "--budget", "4KB", "--no-progress", "--out",
               str(tmp_path / "run")]
    process = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    assert process.stdout.readline().startswith(b"map: N = 300 places")
    process.stdout.close()  # as `| head -1` does
    _, stderr = process.communicate(timeout=180)
    assert process.returncode == EXIT_BROKEN_PIPE, stderr.decode()  # finished, then 141 as `btel train`
    metrics = json.loads((tmp_path / "run" / "metrics.json").read_text())
    assert metrics["run"]["complete"] is True and [r["status"] for r in metrics["results"]] == ["ok"] * 4


@pytest.mark.parametrize("command", ["evaluate", "demo"])
def test_a_run_whose_reader_left_before_its_first_line_still_writes_its_folder(tmp_path: Path, command: str) -> None:
    """`btel evaluate … | true`: the first line (the map's size) found the pipe closed; the folder is still
    written, then the command exits 141 (it exited 141 at once, with no folder)."""
    import json

    from btel.datasets import synthetic_route

    route = synthetic_route(300, 32, seed=0)
    np.save(tmp_path / "db.npy", route.map)
    np.save(tmp_path / "q.npy", route.queries)
    args = (["evaluate", "--db", str(tmp_path / "db.npy"), "--queries", str(tmp_path / "q.npy")] if command == "evaluate"
            else ["demo", "--places", "200", "--dim", "32"])
    process = subprocess.Popen([sys.executable, "-m", "btel.cli", *args, "--methods", "pq", "--budget", "4KB",
                                "--no-progress", "--out", str(tmp_path / "run")],
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    process.stdout.close()
    _, stderr = process.communicate(timeout=180)
    assert process.returncode == EXIT_BROKEN_PIPE, stderr.decode()
    assert "standard output was closed" in stderr.decode()
    metrics = json.loads((tmp_path / "run" / "metrics.json").read_text())
    assert metrics["run"]["complete"] is True and {r["status"] for r in metrics["results"]} == {"ok"}
