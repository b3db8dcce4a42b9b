"""The experiment harness (quick mode) on real Nordland frames, and the report built from it."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from btel.cli import main
from btel.exceptions import BudgetExceededError, DataNotFoundError, InvalidParameterError
from btel.experiments import EXPERIMENTS, NordlandData, run_experiment
from btel.experiments._common import fit_row
from btel.experiments.report import write_report


@pytest.fixture(scope="module")
def quick_runs(nordland_dir: Path, tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("experiments")
    for name in EXPERIMENTS:
        run_experiment(name, data_root=nordland_dir, out_dir=out, cache_dir=out / "cache", quick=True, progress=False)
    return out


@pytest.mark.realdata
@pytest.mark.parametrize("name", list(EXPERIMENTS))
def test_every_experiment_writes_rows_csv_and_plots(name: str, quick_runs: Path) -> None:
    folder = quick_runs / name
    payload = json.loads((folder / "results.json").read_text())
    rows = payload["rows"]
    assert rows, name
    assert (folder / "results.csv").read_text().count("\n") == len(rows) + 1
    assert list(folder.glob("*.png")), f"{name} wrote no plot"
    for row in rows:
        assert "nbytes" in row  # every row carries the method's bytes
        if row["status"] == "ok":
            if row["budget"] is not None:
                assert row["nbytes"] <= row["budget"]
            assert 0.0 <= row["recall@0"] <= row["recall@10"] <= row["recall@20"] <= 1.0
        else:
            assert row["minimum_bytes"] > row["budget"]
    named = sorted({r["descriptor"] for r in rows if r.get("descriptor")})
    if named:  # experiments on several data sets name each row's descriptor, and the run lists them
        assert payload["run"]["descriptor"].startswith("per row: ") and all(d in payload["run"]["descriptor"] for d in named)
    else:
        assert payload["run"]["descriptor"].startswith("HOG")


@pytest.mark.realdata
def test_report_has_every_section_and_keeps_marked_blocks(quick_runs: Path, tmp_path: Path) -> None:
    docs = tmp_path / "docs"
    docs.mkdir()
    (docs / "results.md").write_text("old\n<!-- scale:start -->\nSCALE TABLE\n<!-- scale:end -->\n")
    md = write_report(quick_runs, docs).read_text()
    for name in EXPERIMENTS:
        assert f"btel experiment {name} --quick" in md
    assert "SCALE TABLE" in md and "old" not in md.splitlines()[0]
    # Quick runs are said to be quick under every heading, and no verdict is read from them.
    assert md.count("> **Quick mode**") == len(EXPERIMENTS) and "Reading (computed from the table)" not in md
    # ... nor a count of cells from the frontier's few rows, whose protocol is the quick run's own.
    assert "Quick mode: 4 maps" in md and "seeds 0, 1 (" in md and "Map-only auto ≥ 0.95" not in md
    assert "mean over seeds 0, 1, 2" not in md
    summary = json.loads((docs / "results.json").read_text())
    assert set(summary) == set(EXPERIMENTS)
    row = summary["vs-budget"]["rows"][0]
    assert f"{row['recall@10']:.3f}" in md  # the markdown shows the same numbers as the JSON
    assert all((docs / "figures").iterdir())


@pytest.mark.realdata
def test_a_method_over_its_budget_fails_the_run(nordland_dir: Path, tmp_path: Path, monkeypatch) -> None:
    from btel.methods.btel.localizer import BTELocalizer

    data = NordlandData(nordland_dir, tmp_path / "cache", progress=False, max_frames=100)
    monkeypatch.setattr(BTELocalizer, "nbytes", property(lambda self: 10**9))
    with pytest.raises(BudgetExceededError, match="over its budget"):
        fit_row("btel-c", data, budget="50KB", n_places=100)


def test_bad_names_and_folders(tmp_path: Path) -> None:
    with pytest.raises(InvalidParameterError, match="accuracy"):
        run_experiment("nope", data_root=tmp_path)
    with pytest.raises(DataNotFoundError, match="summer"):
        run_experiment("regions", data_root=tmp_path)  # a folder without the seasons
    with pytest.raises(DataNotFoundError, match="missing' does not exist .*BTEL_SHARED_DATA"):
        run_experiment("regions", data_root=tmp_path / "missing")
    result = CliRunner().invoke(main, ["report", "--runs", str(tmp_path / "none"), "--docs", str(tmp_path)])
    assert result.exit_code != 0 and "btel experiment all" in result.output


def test_the_default_data_folder_follows_btel_shared_data(tmp_path: Path, monkeypatch) -> None:
    """The variable the tests and the own-data guide use: `btel experiment` reads it too."""
    monkeypatch.setenv("BTEL_SHARED_DATA", str(tmp_path / "elsewhere"))
    result = CliRunner().invoke(main, ["experiment", "regions", "--quick", "--out", str(tmp_path / "runs")])
    assert result.exit_code == 2 and f"{tmp_path / 'elsewhere' / 'nordland64'}' does not exist" in result.output


@pytest.mark.realdata
def test_cli_experiment_quick(nordland_dir: Path, quick_runs: Path, tmp_path: Path) -> None:
    out = tmp_path / "runs"
    result = CliRunner().invoke(main, ["experiment", "feature-ratio", "--quick", "--data", str(nordland_dir),
                                       "--out", str(out), "--cache", str(quick_runs / "cache")])
    assert result.exit_code == 0, result.output
    assert "BTE-C c=0.1" in result.output
    rows = json.loads((out / "feature-ratio" / "results.json").read_text())["rows"]
    assert [r["feature_ratio"] for r in rows] == [0.1, 0.3]
    assert np.all(np.diff([r["nbytes"] for r in rows]) > 0)  # more columns, more bytes


@pytest.mark.realdata
def test_an_experiment_run_again_is_refused_unless_overwrite(nordland_dir: Path, quick_runs: Path,
                                                             tmp_path: Path) -> None:
    """A second run into a folder holding results (a quick one over a full one, say) is refused before it
    prints or runs; --overwrite replaces them. Before, it replaced them silently."""
    from btel.exceptions import OutputExistsError

    args = ["experiment", "feature-ratio", "--quick", "--data", str(nordland_dir), "--out", str(tmp_path),
            "--cache", str(quick_runs / "cache")]
    assert CliRunner().invoke(main, args).exit_code == 0
    written = (tmp_path / "feature-ratio" / "results.json").read_bytes()
    result = CliRunner().invoke(main, args)
    assert result.exit_code == 2 and "holds an earlier run (results.json)" in result.output
    assert "--overwrite" in result.output and "…" not in result.output
    assert (tmp_path / "feature-ratio" / "results.json").read_bytes() == written
    # `all` is refused before its first experiment when any of its folders holds a run
    result = CliRunner().invoke(main, [*args[:1], "all", *args[2:]])
    assert result.exit_code == 2 and "feature-ratio" in result.output and "…" not in result.output
    (tmp_path / "frontier").mkdir()
    (tmp_path / "frontier" / "rows.jsonl").write_text("")
    with pytest.raises(OutputExistsError, match="interrupted frontier: --resume takes it up"):
        run_experiment("frontier", data_root=nordland_dir, out_dir=tmp_path, quick=True, progress=False)
    result = CliRunner().invoke(main, [*args, "--overwrite"])
    assert result.exit_code == 0, result.output
    assert "BTE-C c=0.1" in result.output


@pytest.mark.realdata
def test_frontier_in_two_processes_writes_the_rows_of_one(nordland_dir: Path, quick_runs: Path, tmp_path: Path) -> None:
    """`--jobs 2` runs the maps in two processes: the same rows, in map order, each journalled once."""
    result = CliRunner().invoke(main, ["experiment", "frontier", "--quick", "--jobs", "2", "--data", str(nordland_dir),
                                       "--out", str(tmp_path), "--cache", str(quick_runs / "cache")])
    assert result.exit_code == 0, result.output

    def cells(rows: list[dict]) -> list[tuple]:
        return [(r["dataset"], r["method"], r.get("budget"), r["status"], r.get("value"), r.get("chose"))
                for r in rows]

    one = json.loads((quick_runs / "frontier" / "results.json").read_text())
    two = json.loads((tmp_path / "frontier" / "results.json").read_text())
    assert cells(two["rows"]) == cells(one["rows"]) and len(one["rows"]) > 20
    assert two["jobs"] == 2 and two["run"]["jobs"] == 2 and one["jobs"] == 1
    journal = [json.loads(line) for line in (tmp_path / "frontier" / "rows.jsonl").read_text().splitlines()]
    assert sorted(cells(journal), key=repr) == sorted(cells(one["rows"]), key=repr)


def test_the_frontier_runs_its_plan_and_its_bar_counts_the_journal(tmp_path: Path, monkeypatch) -> None:
    """`_map_plan` is what `_one_map` runs, row for row (so the bar's total is right); the bar counts the
    journal's lines, which every process appends to."""
    import io
    import time

    from btel.experiments import frontier, frontier_journal

    X = np.random.default_rng(0).normal(size=(300, 64)).astype(np.float32)
    monkeypatch.setattr(frontier, "_row", lambda base, label, name, params, X, Q, budget, seeds=None: {
        "dataset": base["dataset"], "method": label, "budget": budget, "seeds": seeds})
    monkeypatch.setattr(frontier, "_calibrated_row", lambda base, X, Q, budget, seeds: {
        "dataset": base["dataset"], "method": "auto calibrated", "budget": budget, "seeds": seeds})
    for quick, dataset in ((True, "gardens-point"), (False, "nordland summer→winter"), (False, "synthetic route")):
        budgets = ("4KB", "64KB") if quick else frontier.BUDGETS
        plan = frontier._map_plan(dataset, X, budgets, quick)
        rows, _ = frontier._one_map({"dataset": dataset}, X, X, budgets, quick, tmp_path / "rows.jsonl")
        assert [(r["method"], r["budget"]) for r in rows] == [(p[0], p[3]) for p in plan]
        assert all(r["budget"] is None or r["budget"] <= 300 * 64 * 4 for r in rows)  # no budget over the map
    assert {r["method"] for r in rows} >= {"auto", "auto calibrated", "rabitq", "brute force shrink"}

    class Terminal(io.StringIO):
        def isatty(self) -> bool:
            return True

    journal = tmp_path / "journal.jsonl"
    journal.write_text("")
    with frontier_journal.journal_bar(journal, 5, True, interval=0.01, file=Terminal()) as bar:
        journal.write_text("{}\n{}\n{}\n")
        deadline = time.monotonic() + 5
        while bar.n != 3 and time.monotonic() < deadline:
            time.sleep(0.01)
        assert bar.n == 3 and bar.total == 5
        journal.unlink()  # removed under the run: the watcher waits, and the bar never moves back
        time.sleep(0.1)
        journal.write_text("{}\n")
        time.sleep(0.1)
        assert bar.n == 3
        journal.write_text("{}\n" * 4)
        deadline = time.monotonic() + 5
        while bar.n != 4 and time.monotonic() < deadline:
            time.sleep(0.01)
        assert bar.n == 4
    with frontier_journal.journal_bar(journal, 5, False) as off:
        assert off.disable


def test_an_experiment_interrupted_while_writing_leaves_no_results_json(tmp_path: Path) -> None:
    """results.json, the file `btel report` reads a run by, is written last and whole: an interruption
    while the figures are drawn leaves the previous run's results.json (or none), never a new one
    beside missing figures."""
    from btel.experiments._common import ExperimentRun, write_results

    rows = [{"dataset": "d", "method": "lsh", "budget": 1000, "status": "ok", "nbytes": 900, "value": 0.5}]

    def interrupted(run, out):
        (out / "figure.png").write_bytes(b"half")
        raise KeyboardInterrupt

    for before in (None, '{"run": {"experiment": "earlier"}}\n'):
        out = tmp_path / ("fresh" if before is None else "again")
        out.mkdir()
        if before is not None:
            (out / "results.json").write_text(before)
        run = ExperimentRun.from_rows("frontier", rows, out, plot=interrupted)
        with pytest.raises(KeyboardInterrupt):
            write_results(run, out, {"experiment": "frontier"})
        if before is None:
            assert not (out / "results.json").exists()
        else:
            assert (out / "results.json").read_text() == before
        assert not [p.name for p in out.iterdir() if p.name.startswith(".")]  # no temporaries left
    run = ExperimentRun.from_rows("frontier", rows, tmp_path / "fresh", plot=None)
    write_results(run, tmp_path / "fresh", {"experiment": "frontier"})
    assert json.loads((tmp_path / "fresh" / "results.json").read_text())["rows"][0]["method"] == "lsh"


@pytest.mark.realdata
def test_frontier_resume_keeps_the_journalled_rows_and_runs_the_rest(nordland_dir: Path, quick_runs: Path,
                                                                     tmp_path: Path, monkeypatch) -> None:
    """An interrupted run (its journal cut after 20 rows, the last line cut short, a line of noise) taken
    up with resume: the 20 rows are kept, the rest run, and the rows are the uninterrupted run's."""
    from btel.experiments import frontier
    from btel.experiments.frontier_journal import inputs_digest

    full = json.loads((quick_runs / "frontier" / "results.json").read_text())
    lines = (quick_runs / "frontier" / "rows.jsonl").read_text().splitlines()
    (tmp_path / "frontier").mkdir()
    (tmp_path / "frontier" / "rows.jsonl").write_text("\n".join(lines[:20]) + "\nnot json\n" + lines[20][:50])
    ran = []
    real = frontier._row
    monkeypatch.setattr(frontier, "_row", lambda *a, **k: ran.append(a[1]) or real(*a, **k))
    run_experiment("frontier", data_root=nordland_dir, out_dir=tmp_path, cache_dir=quick_runs / "cache", quick=True,
                   progress=False, resume=True)
    resumed = json.loads((tmp_path / "frontier" / "results.json").read_text())

    def cells(rows: list[dict]) -> list[tuple]:
        return [(r["dataset"], r["method"], r.get("budget"), r["status"], r.get("value")) for r in rows]

    assert cells(resumed["rows"]) == cells(full["rows"]) and resumed["resumed_rows"] == 20
    from btel.experiments.frontier_verdicts import report_lines

    assert "The run was resumed: 20 rows came from" in " ".join(report_lines(resumed, tmp_path))
    assert "resumed" not in " ".join(report_lines(full, tmp_path))
    calibrated = sum(r["method"] == "auto calibrated" for r in full["rows"][20:])
    assert len(ran) == len(full["rows"]) - 20 - calibrated  # every row not journalled, and only those
    assert len((tmp_path / "frontier" / "rows.jsonl").read_text().splitlines()) == len(full["rows"])
    X = np.zeros((4, 3), dtype=np.float32)
    assert len({inputs_digest(X, X, True), inputs_digest(X, X, False), inputs_digest(X + 1, X, True)}) == 3
    with pytest.raises(InvalidParameterError, match="--resume applies to frontier only"):
        run_experiment("regions", data_root=nordland_dir, resume=True)
    from btel.exceptions import OutputExistsError

    (tmp_path / "folder" / "frontier" / "rows.jsonl").mkdir(parents=True)
    with pytest.raises(OutputExistsError, match="is a folder"):
        run_experiment("frontier", data_root=nordland_dir, out_dir=tmp_path / "folder", quick=True, progress=False,
                       resume=True)


def test_the_journal_reader_keeps_only_rows_and_refuses_what_is_no_journal(tmp_path: Path) -> None:
    """--resume reads rows.jsonl: lines that are not rows are left out (so run again); a file far larger
    than any journal, or a FIFO, is refused at once."""
    import os

    from btel.exceptions import DataNotFoundError
    from btel.experiments.frontier_journal import MAX_JOURNAL_BYTES, journal_line, journalled_rows

    journal = tmp_path / "rows.jsonl"
    row = {"dataset": "d", "method": "lsh", "budget": 4000, "inputs": "abc", "value": 0.5}
    edited = journal_line({**row, "method": "pq"}).replace('"value": 0.5', '"value": "abc"')
    journal.write_text("".join([journal_line(row), "[1, 2]\n", '{"method": 3}\n', json.dumps(row) + "\n",
                                journal_line({**row, "budget": "4KB"}), journal_line({**row, "budget": True}),
                                edited, "[" * 5000 + "\n", journal_line({**row, "method": "itq"})[:30]]))
    # Only the row as written: not the one without a checksum, nor the edited one, nor those whose budget is no
    # byte count, nor the nested or cut lines.
    assert journalled_rows(journal) == {"abc": {("lsh", 4000): row}}
    assert journalled_rows(tmp_path / "none.jsonl") == {}
    elsewhere = tmp_path / "notes.txt"
    elsewhere.write_text("my notes\n")
    (tmp_path / "link.jsonl").symlink_to(elsewhere)
    assert journalled_rows(tmp_path / "link.jsonl") == {}
    with open(tmp_path / "huge.jsonl", "wb") as fh:
        fh.truncate(MAX_JOURNAL_BYTES + 1)
    with pytest.raises(InvalidParameterError, match="not one; run without --resume"):
        journalled_rows(tmp_path / "huge.jsonl")
    os.mkfifo(tmp_path / "fifo.jsonl")
    with pytest.raises(DataNotFoundError, match="not a regular file"):
        journalled_rows(tmp_path / "fifo.jsonl")


def test_jobs_is_refused_where_an_experiment_runs_in_one_process(tmp_path: Path) -> None:
    with pytest.raises(InvalidParameterError, match="--jobs applies to frontier only"):
        run_experiment("regions", data_root=tmp_path, jobs=2)
    with pytest.raises(InvalidParameterError, match="whole number"):
        run_experiment("frontier", data_root=tmp_path, jobs=0)
    result = CliRunner().invoke(main, ["experiment", "regions", "--jobs", "0", "--out", str(tmp_path)])
    assert result.exit_code == 2 and "--jobs" in result.output
    result = CliRunner().invoke(main, ["experiment", "regions", "--jobs", "2", "--out", str(tmp_path)])
    assert result.exit_code == 2 and "--jobs applies to frontier only" in result.output


@pytest.mark.parametrize("args, message", [
    (["bogus"], "unknown experiment 'bogus'"),
    (["all", "--delta", "10"], "experiment 'beyond' sets each method's front end itself"),
    (["accuracy", "--resume"], "--resume applies to frontier only"),
])
def test_experiment_refusals_come_before_any_line_or_run(tmp_path: Path, args: list[str], message: str) -> None:
    """A refused request prints only its error: no "experiment … …" start line, no run folder, no
    experiment of an `all` run before the one that refuses."""
    result = CliRunner().invoke(main, ["experiment", *args, "--quick", "--out", str(tmp_path / "runs")])
    assert result.exit_code == 2 and message in result.output
    assert "…" not in result.output and not (tmp_path / "runs").exists()

def test_stretch_split_keeps_validation_and_reported_queries_apart() -> None:
    from btel.experiments.beyond import stretch_split

    val, rep, starts = stretch_split(3576)
    assert np.intersect1d(val, rep).size == 0 and val.size + rep.size == 3576
    np.testing.assert_array_equal(starts[:3], [0, 200, 400])
    stretches = set((val // 200).tolist())
    assert stretches == {0, 5, 10, 15}  # 800 validation queries, 2776 reported


@pytest.mark.realdata
def test_beyond_ladder_diagnostics_and_report(quick_runs: Path, tmp_path: Path) -> None:
    payload = json.loads((quick_runs / "beyond" / "results.json").read_text())
    assert set(payload["ladder"]) == {"summer→winter", "winter→summer"}
    for measures in payload["ladder"].values():
        assert set(measures) == {"single frame recall@10", "ranked R@10 (10 candidates, t = 10)",
                                 "HMM sequence decoding recall@10"}
        for pick in measures.values():
            assert "btel" in pick and 0.0 <= pick["btel"]["value"] <= 1.0
            assert pick["btel"]["nbytes"] <= payload["budget"]
    rows = payload["rows"]
    parts = {r["part"] for r in rows}
    assert parts == {"nordland", "gardens-point", "synthetic"}
    # Every Nordland method is read four ways on equal terms (single, ranked, median, HMM).
    fitted = {(r["direction"], r["method"]) for r in rows if r["part"] == "nordland" and r["status"] == "ok"}
    for direction, method in fitted:
        decoders = {r["decoder"] for r in rows if r.get("direction") == direction and r["method"] == method}
        assert decoders == {"single", "median a=20", "HMM"}
    hmm = [r for r in rows if r.get("decoder") == "HMM"]
    assert all(r["hmm"]["temperature"] > 0 for r in hmm)
    assert set(payload["diagnostics"]) >= {"Nordland HOG summer→winter", "Nordland patch-normalised summer→winter"}
    for curves in payload["diagnostics"].values():
        for diag in curves.values():
            assert all(0.0 <= a <= 1.0 for a in diag["accuracy"] if a is not None and a == a)  # NaN: no query
    pngs = {p.name for p in (quick_runs / "beyond").glob("*.png")}
    assert {"synthetic_crossover.png", "gardens_point_recall_vs_bytes.png"} <= pngs
    assert any(name.startswith("bits_") for name in pngs)
    docs = tmp_path / "docs"
    docs.mkdir()
    md = write_report(quick_runs, docs).read_text()
    assert "### Ladder" in md and "Validation protocol" in md
    summary = json.loads((docs / "results.json").read_text())
    assert summary["beyond"]["ladder"] == payload["ladder"]


def test_frontier_rows_average_seeds_and_pair_them(monkeypatch) -> None:
    """Seeded rows are the mean over the seeds; a seed-independent method runs once; pairs by seed."""
    from btel.datasets import synthetic_route
    from btel.experiments import frontier

    route = synthetic_route(200, 32, condition_shift=1.0, seed=3)
    base = {"dataset": "route", "key": "recall@2", "n_places": 200}
    row = frontier._row(base, "lsh", "lsh", {}, route.map, route.queries, 2000, (0, 1, 2))
    assert row["seeds"] == [0, 1, 2] and len(row["seed_values"]) == 3
    assert row["value"] == pytest.approx(np.mean(row["seed_values"]))
    assert len(set(row["seed_values"])) > 1  # LSH's hyperplanes do depend on the seed here
    unseeded = frontier._row(base, "bruteforce", "bruteforce", {}, route.map, route.queries, None)
    assert unseeded["seeds"] == [] and unseeded["seed_values"] == [unseeded["value"]]

    real = frontier.fit_and_predict
    monkeypatch.setattr(frontier, "fit_and_predict", lambda name, params, *a, **k: real(
        name, {p: v for p, v in params.items() if p != "random_state"}, *a, **k))
    once = frontier._row(base, "lsh", "lsh", {}, route.map, route.queries, 2000, (0, 1, 2))
    assert once["seeds"] == [0] and once["value"] == row["seed_values"][0]

    a, b = {"value": 0.6, "seed_values": [0.5, 0.6, 0.7]}, {"value": 0.5, "seed_values": [0.4, 0.6, 0.5]}
    paired = frontier.paired_difference(a, b)
    assert paired["diff"] == pytest.approx(0.1) and paired["diff_seeds"] == 3
    assert paired["diff_se"] == pytest.approx(0.1 / np.sqrt(3))
    single = frontier.paired_difference({"value": 0.55, "seed_values": [0.55]}, b)
    assert single["diff"] == pytest.approx(0.55 - 0.5) and single["diff_seeds"] == 3


def test_frontier_calibrated_row_answers_each_query_with_a_model_calibrated_on_the_other_half(monkeypatch) -> None:
    """Cross-fitting: the calibration of the model that answers a query never contains that query."""
    from btel.datasets import synthetic_route
    from btel.experiments import frontier
    from btel.methods.auto import AutoLocalizer

    route = synthetic_route(120, 16, condition_shift=1.0, seed=5)
    seen: list[tuple[np.ndarray, np.ndarray]] = []  # (calibration truths, the queries it then answers)
    real_fit, real_predict = AutoLocalizer.fit, AutoLocalizer.predict

    def fit(self, X, places=None, calibration=None):
        self._test_cal = np.asarray(calibration[1])
        return real_fit(self, X, places, calibration)

    def predict(self, Q):
        rows = [int(np.flatnonzero((route.queries == q).all(axis=1))[0]) for q in np.asarray(Q)]
        seen.append((self._test_cal, np.asarray(rows)))
        return real_predict(self, Q)

    monkeypatch.setattr(AutoLocalizer, "fit", fit)
    monkeypatch.setattr(AutoLocalizer, "predict", predict)
    base = {"dataset": "route", "key": "recall@2", "n_places": 120}
    row = frontier._calibrated_row(base, route.map, route.queries, 4000, (0, 1))
    assert row["status"] == "ok" and row["seeds"] == [0, 1] and len(seen) == 4
    for cal, answered in seen:
        assert not set(cal) & set(answered) and len(cal) + len(answered) == 120
    assert row["value"] == pytest.approx(np.mean(row["seed_values"]))
    assert row["value"] == pytest.approx(np.mean(row["half_values"]), abs=1e-9)  # equal halves (N even)
    assert row["nbytes"] <= 4000 and {len(v) for v in row["calibrated_choices"].values()} == {2}


def test_frontier_verdicts_name_autos_pick_and_never_count_auto_as_its_own_oracle() -> None:
    from btel.experiments import frontier, frontier_verdicts

    def row(method, name, options, value, **extra):
        return {"dataset": "m", "budget": 4000, "status": "ok", "key": "recall@0", "method": method,
                "registry_name": name, "options": options, "value": value, "half_values": [value, value],
                "seed_values": [value], **extra}

    rows = [row("lsh", "lsh", {}, 0.50), row("lsh centred", "lsh", {"center": True}, 0.40),
            row("pq", "pq", {}, 0.60),
            row("auto", "auto", {}, 0.40, chose="lsh center=True", chose_method="lsh",
                chose_params={"center": True}, route_share=0.0),
            row("auto calibrated", "auto", {}, 0.99,
                calibrated_choices={"even": [{"chose": "pq", "switched": True}], "odd": []})]
    (v,) = frontier.auto_vs_oracle(rows)
    assert v["best"] == "pq" and v["auto_pick_row"] == "lsh centred"
    assert v["meets_0.95"] is False and v["calibrated_meets_0.95"] is True
    assert v["calibrated_switches"] == 1 and v["calibrated_minus_auto"]["diff"] == pytest.approx(0.59)
    assert "calibrated in 1 of 1" in " ".join(frontier_verdicts._counts([v])).replace("Calibrated auto (every query "
                                                                            "answered by a model calibrated on "
                                                                            "the other half) in", "calibrated in")


def test_protocols_quoted_from_docstrings_read_as_markdown() -> None:
    """The results page quotes protocols from docstrings: no `:mod:` left for a reader to see."""
    from btel.experiments._common import docstring_markdown

    text = "ridge α by the rule of :mod:`btel.methods.codes.solvers`,\n   the :func:`~btel.x.plan` and ``btel-codes``"
    assert docstring_markdown(text) == "ridge α by the rule of `btel.methods.codes.solvers`, the `plan` and `btel-codes`"


def test_frontier_panels_label_no_minor_ticks_so_labels_never_run_together(tmp_path, monkeypatch) -> None:
    """Over less than a decade matplotlib labelled minor ticks: '3×10¹4×10¹' on the bytes-per-place axis.
    The rows are a `btel experiment frontier --quick` run's (tests/data/frontier_quick_rows.jsonl)."""
    from matplotlib.figure import Figure

    from btel.experiments import frontier

    rows = [json.loads(line) for line in (Path(__file__).parent / "data" / "frontier_quick_rows.jsonl").open()]
    drawn = []
    real = Figure.savefig
    monkeypatch.setattr(Figure, "savefig", lambda fig, *a, **k: (drawn.append(fig), real(fig, *a, **k))[1])
    frontier._plots(rows, tmp_path)
    assert len(drawn) == 3  # recall vs bytes, vs bytes per place, and the overview of two maps
    for fig in drawn:
        fig.canvas.draw()
        for ax in fig.axes:
            if not ax.has_data():
                continue
            assert not [t.get_text() for t in ax.xaxis.get_minorticklabels() if t.get_text()]
            labels = [t for t in ax.xaxis.get_majorticklabels() if t.get_text() and t.get_visible()]
            boxes = sorted((t.get_window_extent() for t in labels), key=lambda b: b.x0)
            assert all(a.x1 <= b.x0 for a, b in zip(boxes, boxes[1:]))  # no two labels overlap


def test_frontier_legend_has_a_panel_of_its_own_with_auto_first(tmp_path, monkeypatch) -> None:
    """~30 rows of legend in the first map's panel hid its curves and could not be read at page width:
    the key goes to a panel without data, auto's two rows first, and no map panel carries one."""
    from matplotlib.figure import Figure

    from btel.experiments import frontier

    rows = [json.loads(line) for line in (Path(__file__).parent / "data" / "frontier_quick_rows.jsonl").open()]
    drawn = []
    real = Figure.savefig
    monkeypatch.setattr(Figure, "savefig", lambda fig, *a, **k: (drawn.append(fig), real(fig, *a, **k))[1])
    frontier._plots(rows, tmp_path)
    methods = {r["method"] for r in rows if r.get("status") == "ok"}
    for fig in drawn[:2]:  # the full figures (the overview's few rows share a legend below its panels)
        maps = [ax for ax in fig.axes if ax.has_data()]
        keys = [ax for ax in fig.axes if ax.get_legend() is not None]
        assert len(maps) == len({r["dataset"] for r in rows}) and all(ax.get_legend() is None for ax in maps)
        assert len(keys) == 1 and not keys[0].has_data() and not keys[0].axison
        labels = [t.get_text() for t in keys[0].get_legend().get_texts()]
        assert labels[0] == "auto" and set(labels[:-1]) == methods and labels[-1].startswith("ring")


def test_experiment_takes_no_progress_as_the_other_commands_do(tmp_path: Path, monkeypatch) -> None:
    """`btel experiment --no-progress` was no option (run_experiment's progress was not reachable)."""
    import btel.experiments

    seen = {}

    def record(name, **kwargs):
        seen.update(kwargs)
        raise DataNotFoundError("stop here")

    monkeypatch.setattr(btel.experiments, "run_experiment", record)
    result = CliRunner().invoke(main, ["experiment", "regions", "--quick", "--no-progress", "--out", str(tmp_path)])
    assert result.exit_code == 2 and "stop here" in result.output and seen["progress"] is False


def test_the_overview_draws_two_maps_from_the_frontier_rows(tmp_path: Path) -> None:
    """The README's figure: auto's picks spelled out, only the maps it names; none from a quick run's rows."""
    from btel.experiments.frontier_overview import _picks, plot_overview

    rows = [{"dataset": "gardens-point", "key": "recall@2", "status": "ok", "method": m, "budget": b, "nbytes": b,
             "value": v, "chose_method": "btel-codes" if b < 64000 else "lsh",
             "chose_params": {"center": b >= 64000}}
            for m, v in (("auto", 0.5), ("lsh", 0.4), ("pq", 0.3)) for b in (1000, 16000, 64000, 1000000)]
    assert _picks([r for r in rows if r["method"] == "auto"]) == (
        "auto's pick: btel-codes 1 KB–16 KB, lsh (centred rows) 64 KB–1 MB")
    path = plot_overview(rows, tmp_path / "o.png")
    assert path is not None and path.stat().st_size > 10_000
    assert plot_overview([{**r, "dataset": "synthetic route"} for r in rows], tmp_path / "q.png") is None
    assert not (tmp_path / "q.png").exists()


def test_a_cached_model_swapped_or_damaged_on_disk_is_refitted_not_used(tmp_path: Path) -> None:
    """A model file copied over an entry of an experiment's cache was used: its rows were labelled as the
    cached method's, on the map it was not fitted on; a damaged entry ended the run with exit 2."""
    from btel.experiments._common import ModelCache
    from btel.methods import make_method

    rng = np.random.default_rng(0)
    X, other = (rng.normal(size=(60, 8)).astype(np.float32) for _ in range(2))
    params = {"budget": 2_000}
    first = ModelCache(tmp_path / "cache", min_fit_seconds=0.0)
    model, _, cached = first.fit("pq", params, X)
    assert not cached
    key = ModelCache.key("pq", params, X)
    entry = tmp_path / "cache" / f"{key}.btel.npz"
    assert ModelCache(tmp_path / "cache").fit("pq", params, X)[2]  # a fresh process reads it back
    # Another method, or the same method fitted on other rows, in the entry's place: refitted.
    for foreign in (make_method("lsh", budget=2_000).fit(X), make_method("pq", budget=2_000).fit(other)):
        foreign.save(entry, overwrite=True)
        again, _, cached = ModelCache(tmp_path / "cache", min_fit_seconds=0.0).fit("pq", params, X)
        assert not cached and type(again) is type(model)
        np.testing.assert_array_equal(again.predict(X), model.predict(X))
    entry.write_bytes(b"garbage")  # damaged: refitted and written anew, not refused as "not a btel file"
    again, _, cached = ModelCache(tmp_path / "cache", min_fit_seconds=0.0).fit("pq", params, X)
    assert not cached and ModelCache(tmp_path / "cache").fit("pq", params, X)[2]
