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

import btel
from btel.core import claims as _claims
from btel.evaluation import evaluate
from btel.experiments._common import ModelCache
from btel.methods import make_method
from btel.evaluation.runs import RunWriter


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


# -- issue 34: "no overwrite" is atomic, a failed write leaves nothing, every output has the umask's mode ----
def _fitted(seed: int = 0):
    X = np.random.default_rng(seed).normal(size=(30, 8)).astype(np.float32)
    return make_method("bruteforce").fit(X), X


def _save_in_child(path: str, seed: int, barrier: "mp.synchronize.Barrier", queue: "mp.Queue") -> None:
    model, _ = _fitted(seed)
    barrier.wait()
    try:
        model.save(path, overwrite=False)
        queue.put(f"ok {seed}")
    except FileExistsError as exc:
        queue.put(f"refused {type(exc).__name__}: {exc}")


def test_of_racing_saves_without_overwrite_exactly_one_publishes(tmp_path: Path) -> None:
    import btel

    ctx = mp.get_context("fork" if "fork" in mp.get_all_start_methods() else "spawn")
    for attempt in range(4):
        path = tmp_path / f"m{attempt}.btel.npz"
        barrier, queue = ctx.Barrier(4), ctx.Queue()
        procs = [ctx.Process(target=_save_in_child, args=(str(path), seed, barrier, queue))
                 for seed in range(4)]
        for p in procs:
            p.start()
        for p in procs:
            p.join(60)
        outcomes = sorted(queue.get(timeout=5) for _ in range(4))
        winners = [o for o in outcomes if o.startswith("ok")]
        assert len(winners) == 1, outcomes
        losers = [o for o in outcomes if not o.startswith("ok")]
        assert all(o.startswith("refused OutputExistsError") and "already exists" in o
                   for o in losers), outcomes
        winner_seed = int(winners[0].split()[1])
        X = _fitted(winner_seed)[1]
        assert np.array_equal(btel.load(path).predict(X), np.arange(30))  # the winner's whole model
        assert sorted(p.name for p in tmp_path.iterdir() if p.name.startswith(".")) == []


def test_a_file_that_appears_while_saving_is_kept(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The race made deterministic: another writer publishes while this one writes its temporary."""
    from btel.core import modelfile
    from btel.exceptions import OutputExistsError

    path = tmp_path / "m.btel.npz"
    model, _ = _fitted()
    real_savez = np.savez

    def savez_while_another_publishes(fh, **arrays):
        real_savez(fh, **arrays)
        path.write_bytes(b"the other writer's model")

    monkeypatch.setattr(modelfile.np, "savez", savez_while_another_publishes)
    with pytest.raises(OutputExistsError, match="another process wrote it while this one was writing"):
        model.save(path, overwrite=False)
    assert path.read_bytes() == b"the other writer's model"
    assert [p.name for p in tmp_path.iterdir()] == ["m.btel.npz"]  # no temporary left
    monkeypatch.setattr(modelfile.np, "savez", real_savez)
    with pytest.raises(OutputExistsError, match="already exists"):
        model.save(path, overwrite=False)
    model.save(path, overwrite=True)  # replaces anything (the default keeps a file btel did not write)
    assert path.read_bytes()[:2] == b"PK"


def test_publish_falls_back_to_an_exclusive_create_without_hard_links(tmp_path: Path,
                                                                     monkeypatch: pytest.MonkeyPatch) -> None:
    from btel.exceptions import OutputExistsError

    def no_links(src, dst):
        raise OSError(errno.EPERM, "Operation not permitted")

    monkeypatch.setattr(os, "link", no_links)
    with _claims.atomic_output(tmp_path / "a.txt", overwrite=False, text=True) as fh:
        fh.write("first")
    with pytest.raises(OutputExistsError):
        with _claims.atomic_output(tmp_path / "a.txt", overwrite=False, text=True) as fh:
            fh.write("second")
    assert (tmp_path / "a.txt").read_text() == "first" and len(list(tmp_path.iterdir())) == 1


def test_a_save_by_default_replaces_btel_files_only(tmp_path: Path) -> None:
    """``model.save("db.npy")`` replaced the user's descriptors (overwrite=True was the default)."""
    from btel.exceptions import OutputExistsError

    model, X = _fitted()
    np.save(tmp_path / "db.npy", X)
    (tmp_path / "notes.txt").write_text("mine")
    for name in ("db.npy", "notes.txt"):
        before = (tmp_path / name).read_bytes()
        with pytest.raises(OutputExistsError, match="is not a btel file"):
            model.save(tmp_path / name)
        assert (tmp_path / name).read_bytes() == before
    model.save(tmp_path / "m.btel.npz")
    first = (tmp_path / "m.btel.npz").stat().st_mtime_ns
    model.save(tmp_path / "m.btel.npz")  # a model saved again: replaced
    assert (tmp_path / "m.btel.npz").stat().st_mtime_ns >= first
    np.testing.assert_array_equal(btel.load(tmp_path / "m.btel.npz").predict(X[:5]), model.predict(X[:5]))


def test_python_save_paths_take_overwrite(tmp_path: Path) -> None:
    from btel.datasets import GroundTruth
    from btel.descriptors import get_descriptor
    from btel.exceptions import OutputExistsError
    from btel.evaluation.runs import write_run

    model, X = _fitted()
    targets = {"model": lambda p, o: model.save(p, overwrite=o),
               "descriptor": lambda p, o: get_descriptor("hog").save(p, overwrite=o),
               "ground truth": lambda p, o: GroundTruth.from_places(np.arange(5)).save(p, overwrite=o)}
    for what, save in targets.items():
        path = tmp_path / f"{what}.npz"
        path.write_bytes(b"mine")
        with pytest.raises(OutputExistsError, match="already exists"):
            save(path, False)
        assert path.read_bytes() == b"mine", what
        save(path, True)
        assert path.read_bytes()[:2] == b"PK", what
    row = evaluate(model, X, X, name="nn")
    write_run([row], tmp_path / "run", plots=False)
    with pytest.raises(OutputExistsError, match="not empty"):
        write_run([row], tmp_path / "run", plots=False)


def _cli(*args: object, cwd: Path, fsize: int | None = None, umask: int | None = None,
         wait: bool = True) -> "subprocess.CompletedProcess[str] | subprocess.Popen[str]":
    """``btel ARGS`` in a child process, optionally with a file size limit (a full disk: writes past it
    fail with EFBIG) or a umask."""
    import resource

    def limits() -> None:
        if fsize is not None:
            resource.setrlimit(resource.RLIMIT_FSIZE, (fsize, fsize))
        if umask is not None:
            os.umask(umask)

    command = [sys.executable, "-m", "btel.cli", *map(str, args)]
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    if not wait:
        return subprocess.Popen(command, cwd=cwd, preexec_fn=limits, stdout=subprocess.PIPE,
                                stderr=subprocess.PIPE, text=True, env=env)
    return subprocess.run(command, cwd=cwd, preexec_fn=limits, capture_output=True, text=True, timeout=300,
                          env=env)


def _route_files(folder: Path) -> tuple[Path, Path]:
    from btel.datasets import synthetic_route

    route = synthetic_route(n_places=60, dim=16, seed=1)
    np.save(folder / "db.npy", route.map.astype(np.float32))
    np.save(folder / "q.npy", route.queries.astype(np.float32))
    return folder / "db.npy", folder / "q.npy"


@pytest.mark.skipif(sys.platform == "win32", reason="POSIX process limits")
def test_two_racing_trains_without_overwrite_one_succeeds_the_other_exits_2(tmp_path: Path) -> None:
    import btel

    db, _ = _route_files(tmp_path)
    procs = [_cli("train", db, "-o", "m.npz", "--method", "bruteforce", cwd=tmp_path, wait=False)
             for _ in range(2)]
    results = [(p.wait(timeout=300), *p.communicate()) for p in procs]
    codes = sorted(code for code, _, _ in results)
    assert codes == [0, 2], results
    written = [out for code, out, _ in results if code == 0]
    refused = [err for code, _, err in results if code == 2][0]
    assert "model written" in written[0] and "already exists" in refused and "--overwrite" in refused, results
    assert "Traceback" not in refused
    assert btel.load(tmp_path / "m.npz").n_places_ == 60
    assert sorted(p.name for p in tmp_path.iterdir()) == ["db.npy", "m.npz", "q.npy"]


def _images(folder: Path, n: int = 6) -> Path:
    import cv2

    folder.mkdir()
    rng = np.random.default_rng(0)
    for i in range(n):
        cv2.imwrite(str(folder / f"{i:03d}.png"), rng.integers(0, 255, size=(48, 96), dtype=np.uint8))
    return folder


@pytest.mark.skipif(sys.platform == "win32", reason="POSIX process limits")
def test_a_full_disk_during_extract_leaves_no_partial_file(tmp_path: Path) -> None:
    images = _images(tmp_path / "imgs")
    out = tmp_path / "out"
    out.mkdir()
    # 6 HOG rows of 3780 float32 = 90 KB: a 16 KB limit fails the matrix, a 128 KB one its .json beside it
    # is small enough; the first run fails, nothing is left, the second (no limit) writes both.
    failed = _cli("extract", images, "-o", out / "x.npy", "--no-progress", cwd=tmp_path, fsize=16_000)
    assert failed.returncode == 1, failed.stderr
    assert "could not write" in failed.stderr and "nothing was left behind" in failed.stderr
    assert "Traceback" not in failed.stderr and len(failed.stderr.strip().splitlines()) == 1, failed.stderr
    assert list(out.iterdir()) == []
    done = _cli("extract", images, "-o", out / "x.npy", "--no-progress", cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    assert sorted(p.name for p in out.iterdir()) == ["x.npy", "x.npy.json"]
    assert np.load(out / "x.npy").shape[0] == 6


@pytest.mark.skipif(sys.platform == "win32", reason="POSIX process limits")
def test_a_full_disk_while_saving_a_model_exits_1_and_leaves_nothing(tmp_path: Path) -> None:
    """Found by the writers' fuzz (fault/train, seed 45): a save that failed with EFBIG exited 2, the
    status of a usage error, though nothing was wrong with the command."""
    db, _ = _route_files(tmp_path)
    failed = _cli("train", db, "-o", "m.npz", "--method", "btel-c", cwd=tmp_path, fsize=300)
    assert failed.returncode == 1, (failed.returncode, failed.stderr)
    assert failed.stderr.strip().splitlines() == [failed.stderr.strip().splitlines()[-1]]
    assert "cannot save the model" in failed.stderr and "nothing was left behind" in failed.stderr
    assert not (tmp_path / "m.npz").exists() and not [p for p in tmp_path.iterdir() if p.name.startswith(".")]
    taken = _cli("train", db, "-o", "db.npy", "--method", "btel-c", cwd=tmp_path)
    assert taken.returncode == 2, taken.stderr  # an output that exists is still the user's to fix


def _check_run_folder_is_whole(run: Path) -> list[str]:
    """Every file in a run folder parses completely; no temporary or claim is left. Returns the names."""
    import csv as _csv

    from PIL import Image

    names = sorted(p.name for p in run.iterdir())
    assert not [n for n in names if n.startswith(".")], names
    for path in run.iterdir():
        if path.suffix == ".json":
            json.loads(path.read_text())
        elif path.suffix == ".csv":
            rows = list(_csv.reader(path.read_text().splitlines()))
            assert rows and all(len(r) == len(rows[0]) for r in rows), path
        elif path.suffix == ".png":
            with Image.open(path) as image:
                image.load()  # a truncated PNG raises here
    return names


@pytest.mark.skipif(sys.platform == "win32", reason="POSIX process limits")
@pytest.mark.parametrize("limit", [3_000, 12_000, 28_000])  # fails at metrics.json, the first plot, the last
def test_a_full_disk_during_evaluate_keeps_whole_files_only(tmp_path: Path, limit: int) -> None:
    """Past the limit a write fails (EFBIG): the command ends in one line, and the run folder holds only
    files written whole (the rows finished before the failure), no temporary and no claim."""
    db, q = _route_files(tmp_path)
    result = _cli("evaluate", "--db", db, "--queries", q, "--methods", "bruteforce", "--no-reference",
                  "--out", "run", "--no-progress", cwd=tmp_path, fsize=limit)
    assert result.returncode == 1, (result.returncode, result.stderr)
    assert "Traceback" not in result.stderr and result.stderr.strip().splitlines()[-1].startswith("Error: ")
    assert "could not write" in result.stderr, result.stderr
    names = _check_run_folder_is_whole(tmp_path / "run")
    if limit == 3_000:  # the first metrics.json (9 KB: it records the machine, threads and columns) already fails
        assert names == [], names
    else:  # the rows are on disk; the plots (26–30 KB each) fail at the first or a later one
        assert {"metrics.json", "metrics.csv", "predictions_bruteforce.csv"} <= set(names), names
        assert limit > 12_000 or not [n for n in names if n.endswith(".png")], names


@pytest.mark.skipif(sys.platform == "win32", reason="POSIX umask")
def test_every_output_of_a_run_has_the_umask_mode(tmp_path: Path) -> None:
    db, q = _route_files(tmp_path)
    result = _cli("evaluate", "--db", db, "--queries", q, "--methods", "bruteforce", "--out", "run",
                  "--no-progress", "--pairs", "pairs.txt", cwd=tmp_path, umask=0o027)
    assert result.returncode == 0, result.stderr
    names = _check_run_folder_is_whole(tmp_path / "run")
    assert {"metrics.json", "metrics.csv", "predictions_bruteforce.csv"} <= set(names)
    assert any(n.endswith(".png") for n in names), names
    modes = {p.name: p.stat().st_mode & 0o777 for p in (tmp_path / "run").iterdir()}
    modes.update({p.name: p.stat().st_mode & 0o777 for p in tmp_path.glob("pairs*.txt")})
    assert set(modes.values()) == {0o640}, modes
    trained = _cli("train", db, "-o", "m.npz", "--method", "bruteforce", cwd=tmp_path, umask=0o027)
    assert trained.returncode == 0 and (tmp_path / "m.npz").stat().st_mode & 0o777 == 0o640


@pytest.mark.skipif(sys.platform == "win32", reason="POSIX umask")
def test_outputs_follow_the_umask_in_force_when_written(tmp_path: Path) -> None:
    """Not the umask at import: a long-lived process that changes it gets what ``open`` would give."""
    model, _ = _fitted()
    previous = os.umask(0o077)
    try:
        model.save(tmp_path / "m.btel.npz")
        with _claims.atomic_output(tmp_path / "a.csv", text=True) as fh:
            fh.write("query,prediction\n")
        with open(tmp_path / "plain.txt", "w") as fh:
            fh.write("x")
    finally:
        os.umask(previous)
    modes = {p.name: p.stat().st_mode & 0o777 for p in tmp_path.iterdir()}
    assert modes == {"m.btel.npz": 0o600, "a.csv": 0o600, "plain.txt": 0o600}, modes


@pytest.mark.parametrize("kind", ["fifo", "device", "link to a device"])
def test_a_device_or_fifo_is_never_replaced_overwrite_or_not(tmp_path: Path, kind: str) -> None:
    """Publishing is a rename: over /dev/null or a named pipe it would leave a regular file there."""
    import os
    import stat

    from btel.core.claims import atomic_output
    from btel.exceptions import OutputExistsError

    target = tmp_path / "out.csv"
    if kind == "fifo":
        os.mkfifo(target)
    else:
        target.symlink_to("/dev/null") if kind == "link to a device" else None
        if kind == "device":
            if os.geteuid() != 0:
                pytest.skip("creating a device node needs root; the link case covers the rule")
            os.mknod(target, 0o666 | stat.S_IFCHR, os.makedev(1, 3))
    with pytest.raises(OutputExistsError, match="never replaces"):
        with atomic_output(target, overwrite=True, text=True) as fh:
            fh.write("x\n")
    assert not stat.S_ISREG(os.stat(target).st_mode)
    assert [p.name for p in tmp_path.iterdir()] == ["out.csv"]  # no temporary left behind


@pytest.mark.parametrize("command", ["train", "localize"])
def test_cli_refuses_a_fifo_output_before_any_work(tmp_path: Path, command: str) -> None:
    import os

    from click.testing import CliRunner

    import btel
    from btel.cli import main

    X = np.random.default_rng(0).normal(size=(40, 8)).astype(np.float32)
    np.save(tmp_path / "db.npy", X)
    model = btel.make_method("bruteforce").fit(X).save(tmp_path / "m.npz")
    out = tmp_path / ("out.npz" if command == "train" else "out.csv")
    os.mkfifo(out)
    args = (["train", str(tmp_path / "db.npy"), "-o", str(out), "--method", "bruteforce"]
            if command == "train" else ["localize", str(model), str(tmp_path / "db.npy"), "-o", str(out)])
    done = CliRunner().invoke(main, [*args, "--overwrite"])
    assert done.exit_code == 2 and "is a FIFO (named pipe), not a file" in done.output
