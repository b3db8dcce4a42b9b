"""``btel evaluate --resume RUN`` goes on with the options the run recorded, and the options that would be
ignored or would make a column vanish are refused (``btel.cli.evaluate``, ``btel.evaluation.runs``)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from btel.cli import main
from btel.datasets import synthetic_route


def run(*args: object) -> "click.testing.Result":  # noqa: F821
    return CliRunner().invoke(main, [str(a) for a in args], catch_exceptions=False)


def _rows(out: Path) -> list[tuple[str, str, int | None]]:
    return [(r["name"], r["status"], r["budget"]) for r in json.loads((out / "metrics.json").read_text())["results"]]


@pytest.fixture()
def files(tmp_path: Path) -> tuple[Path, Path]:
    route = synthetic_route(n_places=120, dim=16, seed=1)
    np.save(tmp_path / "db.npy", route.map)
    np.save(tmp_path / "q.npy", route.queries)
    return tmp_path / "db.npy", tmp_path / "q.npy"


@pytest.fixture()
def interrupted(files, tmp_path: Path, monkeypatch) -> tuple[Path, list[str]]:
    """A run of pq, itq at 4KB (R@1, R@5) stopped by Ctrl-C at itq; then ``measure`` records its calls."""
    import btel.evaluation.batch as ev

    real, calls = ev.measure, []

    def measure(method, *args, **kwargs):
        calls.append(kwargs["name"])
        if kwargs["name"] == "itq" and len(calls) == 2:
            raise KeyboardInterrupt
        return real(method, *args, **kwargs)

    monkeypatch.setattr(ev, "measure", measure)
    db, q = files
    out = tmp_path / "run"
    result = run("evaluate", "--db", db, "--queries", q, "--methods", "pq,itq", "--budget", "4KB", "--k", "1,5",
                 "--no-reference", "--no-progress", "--out", out)
    assert result.exit_code == 130, result.output
    assert _rows(out) == [("pq", "ok", 4000), ("itq", "not run", 4000)]
    calls.clear()
    return out, calls


def test_resume_alone_goes_on_with_the_recorded_inputs_and_options(interrupted, tmp_path: Path,
                                                                   monkeypatch) -> None:
    out, calls = interrupted
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)  # the recorded paths are absolute
    result = run("evaluate", "--resume", out, "--no-progress")
    assert result.exit_code == 0, result.output
    assert "1 of 2 rows done (pq)" in result.output and "[1/1] fitting itq (4.0 KB)" in result.output
    assert calls == ["itq"]
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["run"]["complete"] is True and _rows(out) == [("pq", "ok", 4000), ("itq", "ok", 4000)]
    assert all(set(r["recall_at_k"]) == {"1", "5"} for r in metrics["results"])  # the recorded --k
    assert metrics["run"]["extra"]["options"]["--methods"] == ["pq", "itq"]


def test_resume_refuses_options_that_differ_from_the_recorded_ones(interrupted, files) -> None:
    out, calls = interrupted
    result = run("evaluate", "--resume", out, "--budget", "32KB")
    assert result.exit_code == 2
    assert ("--resume: this run was started with --budget 4KB; got 32KB. Start a new run with --out, or drop "
            "--budget to go on with the recorded one.") in " ".join(result.output.split())
    result = run("evaluate", "--resume", out, "--methods", "pq,itq,lsh", "--budget", "32KB", "--k", "1")
    assert result.exit_code == 2
    assert ("this run was started with --methods pq,itq, --budget 4KB, --k 1,5; got --methods pq,itq,lsh, "
            "--budget 32KB, --k 1") in " ".join(result.output.split())
    assert calls == [] and _rows(out) == [("pq", "ok", 4000), ("itq", "not run", 4000)]  # nothing touched
    # The same options given again (a relative path for the absolute one recorded, --methods split) go on.
    db, q = files
    result = run("evaluate", "--resume", out, "--db", db, "--queries", q, "--methods", "pq", "--methods", "itq",
                 "--budget", "4KB", "--no-progress")
    assert result.exit_code == 0, result.output
    assert calls == ["itq"]


def test_resuming_a_complete_run_fits_nothing(interrupted) -> None:
    out, calls = interrupted
    assert run("evaluate", "--resume", out, "--no-progress").exit_code == 0
    calls.clear()
    before = (out / "metrics.json").read_text()
    result = run("evaluate", "--resume", out, "--methods", "pq,itq")  # the recorded options: nothing to do
    assert result.exit_code == 0 and "is a complete run: nothing to resume" in result.output
    # Another option is refused as on an unfinished run: "nothing to resume" must not read as if it were applied.
    result = run("evaluate", "--resume", out, "--methods", "lsh")
    assert result.exit_code == 2 and "this run was started with --methods pq,itq; got lsh." in result.output
    assert calls == [] and (out / "metrics.json").read_text() == before


def test_an_older_run_folder_needs_its_methods_and_keeps_its_rows(interrupted) -> None:
    out, calls = interrupted
    metrics = json.loads((out / "metrics.json").read_text())
    del metrics["run"]["extra"]["options"]  # as written before the options were recorded
    (out / "metrics.json").write_text(json.dumps(metrics))
    result = run("evaluate", "--resume", out)
    assert result.exit_code == 2 and "did not record its options; give --methods again" in result.output
    result = run("evaluate", "--resume", out, "--methods", "itq")  # would drop the pq row done
    assert result.exit_code == 2 and "has rows ['pq'] that these methods and options do not make" in result.output
    result = run("evaluate", "--resume", out, "--methods", "pq,itq", "--budget", "8KB")  # the budget is recorded
    assert result.exit_code == 2 and "started with --budget 4KB; got 8KB" in result.output
    # The options not recorded then are given again, as the interrupted run had them.
    result = run("evaluate", "--resume", out, "--methods", "pq,itq", "--no-reference", "--no-progress")
    assert result.exit_code == 0, result.output
    assert calls == ["itq"] and _rows(out) == [("pq", "ok", 4000), ("itq", "ok", 4000)]


def test_options_a_saved_model_would_ignore_are_refused(files, tmp_path: Path) -> None:
    db, q = files
    model = tmp_path / "m.npz"
    assert run("train", db, "-o", model, "--method", "pq", "--budget", "4KB", "--no-progress").exit_code == 0
    for extra, named in ((["--budget", "8KB"], "--budget"), (["--methods", "itq"], "--methods")):
        result = run("evaluate", "--model", model, "--queries", q, *extra, "--out", tmp_path / "r")
        assert result.exit_code == 2, result.output
        assert f"{named} without --db: nothing is fitted" in result.output and f"Drop {named}" in result.output
    result = run("evaluate", "--model", model, "--queries", q, "--out", tmp_path / "r", "--no-progress")
    assert result.exit_code == 0, result.output


def test_a_k_above_the_map_is_refused_and_a_default_one_left_out_with_a_note(files, tmp_path: Path) -> None:
    db, q = files
    result = run("evaluate", "--db", db, "--queries", q, "--methods", "pq", "--k", "1,1000", "--out", tmp_path / "r")
    assert result.exit_code == 2 and "--k 1000: R@K needs K ≤ the map's N = 120 places" in result.output
    assert not (tmp_path / "r").exists()
    small = synthetic_route(n_places=18, dim=16, seed=0)
    np.save(tmp_path / "db18.npy", small.map)
    np.save(tmp_path / "q18.npy", small.queries)
    out = tmp_path / "small"
    result = run("evaluate", "--db", tmp_path / "db18.npy", "--queries", tmp_path / "q18.npy", "--methods", "lsh",
                 "--budget", "1KB", "--no-reference", "--no-progress", "--out", out)
    assert result.exit_code == 0, result.output
    assert "note: K = 20 of the default --k left out: R@K needs K ≤ the map's N = 18 places." in result.output
    assert set(json.loads((out / "metrics.json").read_text())["results"][0]["recall_at_k"]) == {"1", "5", "10"}


def test_repeated_methods_and_budgets_are_joined(files, tmp_path: Path) -> None:
    db, q = files
    out = tmp_path / "r"
    result = run("evaluate", "--db", db, "--queries", q, "--methods", "pq", "--methods", "itq", "--budget", "4KB",
                 "--budget", "8KB", "--no-reference", "--no-progress", "--out", out)
    assert result.exit_code == 0, result.output
    assert [name for name, *_ in _rows(out)] == ["pq@4KB", "pq@8KB", "itq@4KB", "itq@8KB"]


def test_the_progress_count_has_no_gap_for_a_row_that_cannot_run(tmp_path: Path) -> None:
    route = synthetic_route(n_places=200, dim=32, seed=0)
    np.save(tmp_path / "db.npy", route.map)
    np.save(tmp_path / "q.npy", route.queries)
    # 1.2 KB fits pq and btel-c, not seqslam (≥ 6408 B): two rows run, counted 1 and 2 of 2.
    result = run("evaluate", "--db", tmp_path / "db.npy", "--queries", tmp_path / "q.npy", "--methods",
                 "pq,seqslam,btel-c", "--budget", "1.2KB", "--no-reference", "--no-progress", "--out", tmp_path / "r")
    steps = [line.split()[0] for line in result.output.splitlines() if line.startswith("[")]
    assert steps == ["[1/2]", "[2/2]"], result.output


def test_sigterm_ends_a_run_as_ctrl_c_does_and_resume_goes_on(files, tmp_path: Path, monkeypatch) -> None:
    """``timeout``, SLURM and ``docker stop`` send SIGTERM: exit 143, the finished rows on disk, the folder
    released, and the caller's own SIGTERM handler given back."""
    import os
    import signal

    import btel.evaluation.batch as ev

    real = ev.measure

    def measure(method, *args, **kwargs):
        if kwargs["name"] == "itq":
            os.kill(os.getpid(), signal.SIGTERM)  # arrives at the next bytecode, as from outside
        return real(method, *args, **kwargs)

    before = signal.getsignal(signal.SIGTERM)
    monkeypatch.setattr(ev, "measure", measure)
    db, q = files
    out = tmp_path / "run"
    result = run("evaluate", "--db", db, "--queries", q, "--methods", "pq,itq", "--budget", "4KB",
                 "--no-reference", "--no-progress", "--out", out)
    assert result.exit_code == 143, result.output
    assert _rows(out) == [("pq", "ok", 4000), ("itq", "not run", 4000)]
    assert not (out / ".btel-run.lock").exists()
    assert signal.getsignal(signal.SIGTERM) is before
    monkeypatch.setattr(ev, "measure", real)
    resumed = run("evaluate", "--resume", out, "--no-progress")
    assert resumed.exit_code == 0, resumed.output
    assert _rows(out) == [("pq", "ok", 4000), ("itq", "ok", 4000)]


def test_resume_refuses_inputs_changed_since_the_run_started_and_keeps_the_first_command(
        interrupted, files, monkeypatch) -> None:
    """Rows done on the old map must not be mixed with rows on a new one; the run says how it began."""
    out, calls = interrupted
    db, q = files
    first = json.loads((out / "metrics.json").read_text())["run"]
    assert first["extra"]["inputs"]["--db"]["bytes"] == db.stat().st_size
    assert first["extra"]["shapes"] == {"queries": [120, 16], "db": [120, 16]}
    original = db.read_bytes()
    np.save(db, np.load(db)[::-1])  # the same shape, other rows: nothing else would notice
    refused = run("evaluate", "--resume", out, "--no-progress")
    assert refused.exit_code == 2 and "--db changed since" in refused.output
    assert calls == []  # refused before anything was fitted
    db.write_bytes(original)
    resumed = run("evaluate", "--resume", out, "--no-progress")
    assert resumed.exit_code == 0, resumed.output
    meta = json.loads((out / "metrics.json").read_text())["run"]
    assert (meta["command"], meta["date_utc"]) == (first["command"], first["date_utc"])
    assert len(meta["resumed"]) == 1 and meta["resumed"][0]["date_utc"] >= first["date_utc"]  # this resume
    assert meta["complete"] is True


def test_changed_inputs_compares_bytes_of_every_file(tmp_path: Path) -> None:
    from btel.evaluation.resume import changed_inputs, input_fingerprints

    (tmp_path / "shards").mkdir()
    np.save(tmp_path / "shards" / "shard_0.npy", np.zeros((3, 2)))
    (tmp_path / "gt.csv").write_text("query,positive\n0,1\n")
    given = {"--db": str(tmp_path / "shards"), "--ground-truth": str(tmp_path / "gt.csv"), "--calibrate": None}
    before = input_fingerprints(given)
    assert set(before) == {"--db", "--ground-truth"}
    assert changed_inputs(before, input_fingerprints(given)) == []
    np.save(tmp_path / "shards" / "shard_1.npy", np.zeros((1, 2)))  # a shard added to the folder
    (tmp_path / "gt.csv").write_text("query,positive\n0,2\n")
    assert changed_inputs(before, input_fingerprints(given)) == ["--db", "--ground-truth"]


def test_inputs_are_fingerprinted_only_once_their_readers_accepted_them(files, tmp_path: Path, monkeypatch) -> None:
    """A ground truth whose header claims 2.5·10⁹ places in a sparse file (4 KB on disk, 20 GB by its size) is
    refused by its reader before any input is hashed (hashing it first took a minute; a larger claim, hours)."""
    import btel.evaluation.resume as resume

    hashed: list[str] = []
    real = resume.fingerprint
    monkeypatch.setattr(resume, "fingerprint", lambda text: (hashed.append(text), real(text))[1])
    db, q = files
    sparse = tmp_path / "sparse_gt.npy"
    with open(sparse, "wb") as fh:
        np.lib.format.write_array_header_1_0(fh, {"descr": "<i8", "fortran_order": False, "shape": (2_500_000_000,)})
        fh.truncate(fh.tell() + 20_000_000_000)
    result = run("evaluate", "--db", db, "--queries", q, "--ground-truth", sparse, "--methods", "lsh", "--budget",
                 "2KB", "--out", tmp_path / "run", "--no-progress")
    assert result.exit_code == 2 and hashed == []
    result = run("evaluate", "--db", db, "--queries", q, "--methods", "lsh", "--budget", "2KB", "--out",
                 tmp_path / "run", "--no-progress")
    assert result.exit_code == 0, result.output
    assert str(db) in hashed and str(q) in hashed
    recorded = json.loads((tmp_path / "run" / "metrics.json").read_text())["run"]["extra"]["inputs"]
    assert set(recorded) == {"--db", "--queries"}


def test_resume_compares_budgets_in_bytes(interrupted) -> None:
    """``--resume RUN --budget 4000`` on a run started with 4KB was refused as another budget."""
    out, calls = interrupted
    result = run("evaluate", "--resume", out, "--budget", "4000", "--no-progress")
    assert result.exit_code == 0, result.output
    assert calls == ["itq"] and _rows(out) == [("pq", "ok", 4000), ("itq", "ok", 4000)]



def test_an_interrupted_demo_is_not_resumed_and_says_how_to_run_it_again(tmp_path: Path, monkeypatch) -> None:
    """A demo regenerates its route: `evaluate --resume` on its folder names the demo command to run again
    (it said the folder was written by an older btel); the folder records the demo's options."""
    import btel.evaluation.batch as ev

    real = ev.measure

    def measure(method, *args, **kwargs):
        if kwargs["name"] == "lsh":
            raise KeyboardInterrupt
        return real(method, *args, **kwargs)

    monkeypatch.setattr(ev, "measure", measure)
    out = tmp_path / "demo"
    result = CliRunner().invoke(main, ["demo", "--places", "150", "--dim", "16", "--methods", "pq,lsh", "--budget",
                                       "4KB", "--no-progress", "--out", str(out)])
    assert result.exit_code == 130, result.output
    extra = json.loads((out / "metrics.json").read_text())["run"]["extra"]
    assert {k: extra[k] for k in ("places", "dim", "methods", "reference")} == {
        "places": 150, "dim": 16, "methods": ["pq", "lsh"], "reference": True}
    result = CliRunner().invoke(main, ["evaluate", "--resume", str(out)])
    assert result.exit_code == 2 and "is a `btel demo` run" in result.output
    assert f"btel demo --out {out} --overwrite" in result.output and "older btel" not in result.output
