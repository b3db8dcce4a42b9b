"""Runs that cannot collide (issue 20, findings 7 and 9): an atomic claim on the run folder, unique
temporaries in the experiment cache, dead writers' leftovers removed, a full disk keeps rows."""

from __future__ import annotations

import errno
import json
import multiprocessing as mp
import os
import subprocess
import sys
import threading
from pathlib import Path

import numpy as np
import pytest

from btel import _claims
from btel.evaluation import evaluate
from btel.experiments._common import ModelCache
from btel.methods import make_method
from btel.runs import RunWriter


def _dead_pid() -> int:
    proc = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True)
    return int(proc.stdout)


def _claim_in_child(folder: str, barrier: "mp.synchronize.Barrier", queue: "mp.Queue") -> None:
    barrier.wait()
    try:
        writer = RunWriter(folder)
        queue.put("ok")
        barrier.wait()  # hold the claim until the other process has tried
        writer.close()
    except FileExistsError as exc:
        queue.put(f"refused: {exc}")
        barrier.wait()


def test_two_runs_started_together_cannot_both_claim_a_folder(tmp_path: Path) -> None:
    ctx = mp.get_context("fork" if "fork" in mp.get_all_start_methods() else "spawn")
    for attempt in range(5):
        folder = str(tmp_path / f"run{attempt}")
        barrier, queue = ctx.Barrier(2), ctx.Queue()
        procs = [ctx.Process(target=_claim_in_child, args=(folder, barrier, queue)) for _ in range(2)]
        for p in procs:
            p.start()
        for p in procs:
            p.join(60)
        outcomes = sorted(queue.get(timeout=5) for _ in range(2))
        assert outcomes[0] == "ok" and outcomes[1].startswith("refused: another btel run"), outcomes


def test_a_dead_runs_claim_and_temporaries_do_not_block(tmp_path: Path) -> None:
    folder = tmp_path / "run"
    folder.mkdir()
    dead = _dead_pid()
    (folder / ".btel-run.lock").write_text(f"{dead}\n")
    (folder / f".metrics.json.{dead}.x1.tmp").write_text("half")
    writer = RunWriter(folder)  # the folder counts as empty: only a dead run's claim and temporary
    assert not (folder / f".metrics.json.{dead}.x1.tmp").exists()
    writer.close()
    assert not (folder / ".btel-run.lock").exists()


def _row(name: str):
    X = np.random.default_rng(0).normal(size=(30, 8)).astype(np.float32)
    return evaluate(make_method("bruteforce"), X, X, name=name)


def test_a_full_disk_keeps_the_finished_rows_and_no_temporary(tmp_path: Path,
                                                              monkeypatch: pytest.MonkeyPatch) -> None:
    writer = RunWriter(tmp_path / "run")
    first = _row("a")
    writer.write([first])
    real_replace = os.replace

    def full(src, dst):  # the disk fills up as the second row is written
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(os, "replace", full)
    with pytest.raises(OSError, match="rows finished before are kept"):
        writer.write([first, _row("b")])
    monkeypatch.setattr(os, "replace", real_replace)
    rows = json.loads((tmp_path / "run" / "metrics.json").read_text())["results"]
    assert [r["name"] for r in rows] == ["a"]
    assert not [p.name for p in (tmp_path / "run").iterdir() if p.name.endswith(".tmp")]
    writer.close()


def test_concurrent_cache_puts_of_one_key_all_succeed(tmp_path: Path) -> None:
    X = np.random.default_rng(0).normal(size=(30, 8)).astype(np.float32)
    model = make_method("bruteforce").fit(X)
    caches = [ModelCache(tmp_path / "cache", min_fit_seconds=0.0) for _ in range(40)]
    errors: list[BaseException] = []

    def put(cache: ModelCache) -> None:
        try:
            cache.put("key", model, 1.0, {"method": "bruteforce"})
        except BaseException as exc:  # noqa: BLE001 - recorded for the assertion
            errors.append(exc)

    threads = [threading.Thread(target=put, args=(c,)) for c in caches]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert errors == []
    assert sorted(p.name for p in (tmp_path / "cache").iterdir()) == ["key.btel.npz", "key.json"]
    assert ModelCache(tmp_path / "cache").get("key") is not None


def test_a_killed_saves_part_file_is_removed_by_the_next_save(tmp_path: Path) -> None:
    X = np.random.default_rng(0).normal(size=(30, 8)).astype(np.float32)
    dead = _dead_pid()
    stale = tmp_path / f".m.btel.{dead}.abc123.part"
    live = tmp_path / f".m.btel.{os.getpid()}.zzz.part"  # a save still running in this process
    stale.write_bytes(b"x" * 1000)
    live.write_bytes(b"y")
    make_method("bruteforce").fit(X).save(tmp_path / "m.btel")
    assert not stale.exists() and live.exists()
    assert _claims.remove_stale_temporaries(tmp_path, "m.btel", ".part") == 0


def test_pid_alive() -> None:
    assert _claims.pid_alive(os.getpid()) and not _claims.pid_alive(_dead_pid()) and not _claims.pid_alive(0)
