"""`btel evaluate` / `btel demo` as a VPR researcher uses them (issue #14): nothing lost, nothing cryptic.

Each test names the numbered point of the issue it pins down.
"""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from btel.cli import main
from btel.datasets import GroundTruth, synthetic_route
from btel.evaluation import EvaluationResult, Job, evaluate_all, format_table, preflight
from btel.evaluation.tables import PR_TABLE_NAMES
from btel.exceptions import BudgetTooSmallError
from btel.methods import METHODS, make_method
from btel.evaluation.runs import RunWriter


def run(*args: object) -> "click.testing.Result":  # noqa: F821
    return CliRunner().invoke(main, [str(a) for a in args], catch_exceptions=False)


@pytest.fixture()
def route_files(tmp_path: Path) -> tuple[Path, Path]:
    route = synthetic_route(n_places=200, dim=32, seed=0)
    np.save(tmp_path / "db.npy", route.map)
    np.save(tmp_path / "q.npy", route.queries)
    return tmp_path / "db.npy", tmp_path / "q.npy"


def _csv_rows(path: Path) -> list[dict[str, str]]:
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


# -- 1, 2: a method that does not fit is a row; all of them are reported before any fit -----------------
def test_methods_that_do_not_fit_become_rows_and_are_listed_before_fitting(route_files, tmp_path: Path) -> None:
    """Item 1 and 2: 1.2 KB fits btel-c and pq but not itq (≥ 1352 B) or seqslam (≥ 6408 B); the run
    goes on, keeps every row, lists both failures before the first fit, and exits 3."""
    db, q = route_files
    out = tmp_path / "run"
    result = run("evaluate", "--db", db, "--queries", q, "--methods", "btel-c,itq,seqslam,pq", "--budget", "1.2KB",
                 "--param", "btel-c:progress=false", "--no-progress", "--out", out)
    assert result.exit_code == 1, result.output
    text = result.output
    assert "2 of 6 rows cannot run" in text
    first_fit = text.index("[1/4] fitting")  # the count is of the 4 rows that run
    assert text.index("itq: does not fit") < first_fit and text.index("seqslam: does not fit") < first_fit
    rows = {r["method"]: r for r in _csv_rows(out / "metrics.csv")}
    assert list(rows) == ["btel-c", "itq", "seqslam", "pq", "bruteforce", "bruteforce shrink"]
    assert {m: r["status"] for m, r in rows.items()} == {
        "btel-c": "ok", "itq": "does not fit", "seqslam": "does not fit", "pq": "ok", "bruteforce": "ok",
        "bruteforce shrink": "ok"}
    assert "too small for ITQ" in rows["itq"]["reason"] and rows["pq"]["recall@0"] != ""
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["run"]["complete"] is True
    assert metrics["results"][1]["minimum_bytes"] == 1352 and metrics["results"][2]["minimum_bytes"] == 6408
    assert (out / "predictions_pq.csv").is_file() and not (out / "predictions_itq.csv").exists()


@pytest.mark.slow
def test_preflight_agrees_with_fit_for_every_method() -> None:
    """Item 2: the budget check before fitting raises exactly when fit would, with the same minimum."""
    X = np.random.default_rng(0).normal(size=(260, 24)).astype(np.float32)
    checked = 0
    for name in METHODS:
        if name == "btel-r":  # r = 20 fixed: region sizes come from KTS, so only the fit can tell
            continue
        for budget in (300, 2_500, 30_000):
            params = {"budget": budget}
            if "progress" in make_method(name).get_params():
                params["progress"] = False
            found = preflight([Job(name, make_method(name, **params))], *X.shape).get(name)
            try:
                make_method(name, **params).fit(X)
                fitted = None
            except BudgetTooSmallError as exc:
                fitted = exc.minimum
            assert (found is None) == (fitted is None), (name, budget, found and found.reason)
            if found is not None:
                assert found.status == "does not fit" and found.minimum_bytes == fitted, (name, budget)
                checked += 1
    assert checked >= 6  # the small budgets really exclude several methods
    # Too few places for the method's structure (regions, sub-quantisers, periods): known before fitting too.
    tiny = X[:10]
    refused = 0
    for name in METHODS:
        params = {"progress": False} if "progress" in make_method(name).get_params() else {}
        found = preflight([Job(name, make_method(name, **params))], *tiny.shape).get(name)
        try:
            make_method(name, **params).fit(tiny)
            error = None
        except (ValueError, RuntimeError) as exc:
            error = str(exc)
        assert (found is None) == (error is None), (name, found and found.reason, error)
        if found is not None:
            assert found.status == "failed" and found.reason == " ".join(error.split()), name
            refused += 1
    assert refused >= 1  # btel-r (20 regions) at least; pq and opq take 3-bit sub-quantisers on 10 rows


def test_a_failing_method_is_a_row_and_ctrl_c_keeps_finished_rows(tmp_path: Path) -> None:
    """Item 1: an error inside one fit is a "failed" row; Ctrl-C keeps the rows already written."""
    route = synthetic_route(n_places=120, dim=16, seed=1)

    class Broken:
        def fit(self, X):
            raise RuntimeError("faiss ran out of something")

    class Interrupting:
        def fit(self, X):
            raise KeyboardInterrupt

    writer = RunWriter(tmp_path / "run")
    jobs = [Job("nn", make_method("bruteforce")), Job("broken", Broken()), Job("pq", make_method("pq", budget="4KB")),
            Job("stop", Interrupting()), Job("after", make_method("bruteforce"))]
    with pytest.raises(KeyboardInterrupt):
        evaluate_all(jobs, route.map, route.queries, on_result=writer.write)
    rows = {r["method"]: r for r in _csv_rows(tmp_path / "run" / "metrics.csv")}
    assert {m: r["status"] for m, r in rows.items()} == {
        "nn": "ok", "broken": "failed", "pq": "ok", "stop": "not run", "after": "not run"}
    assert rows["broken"]["reason"] == "RuntimeError: faiss ran out of something"
    assert float(rows["nn"]["recall@0"]) == 1.0 or float(rows["nn"]["recall@0"]) > 0.5
    assert json.loads((tmp_path / "run" / "metrics.json").read_text())["run"]["complete"] is False


# -- 3: everything checkable is checked before fitting ----------------------------------------------------
def test_existing_folder_and_ground_truth_counts_are_checked_before_any_fit(route_files, tmp_path: Path) -> None:
    db, q = route_files
    out = tmp_path / "taken"
    out.mkdir()
    (out / "metrics.json").write_text("{}")
    result = run("evaluate", "--db", db, "--queries", q, "--methods", "btel-c,pq", "--out", out, "--no-progress")
    # An output that exists without --overwrite is bad usage (2), as for train -o and --pairs.
    assert result.exit_code == 2 and "already exists" in result.output and "] fitting" not in result.output
    assert "give --overwrite" in result.output
    GroundTruth.from_places(np.arange(150)).save(tmp_path / "gt.npz")
    result = run("evaluate", "--db", db, "--queries", q, "--methods", "btel-c", "--ground-truth", tmp_path / "gt.npz",
                 "--out", tmp_path / "new", "--no-progress")
    assert result.exit_code == 2 and "] fitting" not in result.output
    assert "--ground-truth" in result.output and "ground_truth=" not in result.output
    assert "150 queries but there are 200" in result.output and not (tmp_path / "new").exists()


# -- 4: brute force is the unbudgeted reference, in demo and evaluate alike --------------------------------
def test_brute_force_is_always_the_unbudgeted_reference(route_files, tmp_path: Path) -> None:
    db, q = route_files
    # Added by the command: cosine brute force and the same on shrinkage-whitened rows, both unbudgeted.
    # Named in --methods: the user's own reference, one row.
    for args, names in ((["evaluate", "--db", db, "--queries", q, "--methods", "pq,bruteforce"], ["bruteforce"]),
                        (["demo", "--places", "200", "--dim", "32", "--methods", "pq"],
                         ["bruteforce", "bruteforce shrink"])):
        out = tmp_path / args[0]
        result = run(*args, "--budget", "5KB", "--out", out, "--no-progress")
        assert result.exit_code == 0, result.output
        results = json.loads((out / "metrics.json").read_text())["results"]
        reference = [r for r in results if r["reference"]]
        assert [r["name"] for r in reference] == names and all(r["budget"] is None for r in reference)
        assert reference[0]["nbytes"] == 200 * 32 * 4 > 5_000  # unbudgeted: the whole map
        assert "bruteforce*" in result.output and "reference (unbudgeted)" in result.output
        assert "is the unbudgeted reference" in " ".join(run(args[0], "--help").output.split())
    white = reference[1]
    assert white["settings"] == {"whiten": "shrink"} and "bruteforce shrink*" in result.output
    assert white["nbytes"] > 200 * 32 * 4  # the whitening's mean and basis are counted on top of the map
    # A front end given to the reference by --param makes it the user's own: no second row.
    out = tmp_path / "own"
    result = run("evaluate", "--db", db, "--queries", q, "--methods", "pq", "--budget", "5KB", "--param",
                 "bruteforce:whiten=16", "--out", out, "--no-progress")
    assert result.exit_code == 0, result.output
    assert [r["name"] for r in json.loads((out / "metrics.json").read_text())["results"]] == ["pq", "bruteforce"]
    out = tmp_path / "none"
    result = run("evaluate", "--db", db, "--queries", q, "--methods", "pq", "--budget", "5KB", "--no-reference",
                 "--out", out, "--no-progress")
    assert [r["name"] for r in json.loads((out / "metrics.json").read_text())["results"]] == ["pq"]


# -- 5: every method ranks in the harness, and R@1 is its point prediction --------------------------------
def test_every_registered_method_gets_r_at_k_with_r1_equal_to_recall0() -> None:
    route = synthetic_route(n_places=150, dim=24, seed=2)
    jobs = []
    for name in METHODS:
        params = {"progress": False} if "progress" in make_method(name).get_params() else {}
        if name == "btel-r":
            params["n_regions"] = 3
        jobs.append(Job(name, make_method(name, **params)))
    results = evaluate_all(jobs, route.map, route.queries, ks=(1, 5, 10))
    for r in results:
        assert r.ok, (r.name, r.reason)
        assert set(r.recall_at_k) == {1, 5, 10}, r.name
        assert r.recall_at_k[1] == r.recall[0], r.name
        assert r.recall_at_k[1] <= r.recall_at_k[5] <= r.recall_at_k[10], r.name
    header = format_table(results).splitlines()[0]
    assert "R@1" in header and "R@10" in header and "recall@0" in header


# -- 6: the metrics the ground truth supports ----------------------------------------------------------------
def test_positives_give_r_at_k_only_and_tolerances_follow_the_route(route_files, tmp_path: Path) -> None:
    db, q = route_files
    positives = [[j, j + 1] if j + 1 < 200 else [j] for j in range(200)]
    GroundTruth.from_positives(positives, n_map=200).save(tmp_path / "pos.npz")
    out = tmp_path / "pos"
    result = run("evaluate", "--db", db, "--queries", q, "--methods", "pq", "--budget", "5KB",
                 "--ground-truth", tmp_path / "pos.npz", "--out", out, "--no-progress")
    assert result.exit_code == 0, result.output
    header = next(line for line in result.output.splitlines() if line.startswith("method"))
    assert "recall@" not in header and header.split()[-7:] == ["R@1", "R@5", "R@10", "R@20", *PR_TABLE_NAMES]
    assert (out / "recall_at_k.png").is_file() and not (out / "recall_vs_tolerance.png").exists()
    result = run("evaluate", "--db", db, "--queries", q, "--ground-truth", tmp_path / "pos.npz", "--tolerances", "0,5",
                 "--out", tmp_path / "x")
    assert result.exit_code == 2 and "explicit positives" in result.output

    # A 111-place route: tolerances up to a tenth of it; --tolerances and --k choose others.
    route = synthetic_route(n_places=111, dim=16, seed=0)
    np.save(tmp_path / "db111.npy", route.map)
    np.save(tmp_path / "q111.npy", route.queries)
    out = tmp_path / "r111"
    result = run("evaluate", "--db", tmp_path / "db111.npy", "--queries", tmp_path / "q111.npy", "--methods", "pq",
                 "--no-reference", "--out", out, "--no-progress")
    header = next(line for line in result.output.splitlines() if line.startswith("method"))
    assert header.split()[-12:] == ["recall@0", "recall@1", "recall@2", "recall@5", "recall@10", "R@1", "R@5", "R@10",
                                    "R@20", *PR_TABLE_NAMES]
    assert len(json.loads((out / "metrics.json").read_text())["results"][0]["recall_curve"]) == 21
    result = run("evaluate", "--db", tmp_path / "db111.npy", "--queries", tmp_path / "q111.npy", "--methods", "pq",
                 "--no-reference", "--tolerances", "3,0", "--k", "2", "--out", tmp_path / "r111b", "--no-progress")
    header = next(line for line in result.output.splitlines() if line.startswith("method"))
    assert header.split()[-6:] == ["recall@0", "recall@3", "R@2", *PR_TABLE_NAMES]


# -- 8: sequence methods are marked, and refused on independent queries ----------------------------------
def test_sequence_methods_are_marked_and_refused_when_rows_are_not_a_route(route_files, tmp_path: Path) -> None:
    db, q = route_files
    out = tmp_path / "route"
    result = run("evaluate", "--db", db, "--queries", q, "--methods", "seqslam,pq", "--param", "pq:delta=3",
                 "--no-reference", "--out", out, "--no-progress")
    assert result.exit_code == 0, result.output
    assert "seqslam†" in result.output and "pq†" in result.output and "uses the query sequence" in result.output
    assert [r["uses_query_sequence"] for r in _csv_rows(out / "metrics.csv")] == ["1", "1"]
    out = tmp_path / "independent"
    result = run("evaluate", "--db", db, "--queries", q, "--methods", "seqslam,btel-c,pq", "--param", "pq:delta=3",
                 "--param", "btel-c:progress=false", "--query-order", "independent", "--out", out, "--no-progress")
    assert result.exit_code == 1, result.output
    status = {r["method"]: r["status"] for r in _csv_rows(out / "metrics.csv")}
    assert status == {"seqslam": "refused", "btel-c": "ok", "pq": "refused", "bruteforce": "ok",
                      "bruteforce shrink": "ok"}


# -- 11: progress per method and per budget ------------------------------------------------------------------
def test_one_progress_step_per_method_and_budget(route_files, tmp_path: Path) -> None:
    db, q = route_files
    out = tmp_path / "budgets"
    result = run("evaluate", "--db", db, "--queries", q, "--methods", "pq,itq", "--budget", "4KB,8KB",
                 "--out", out, "--no-progress")
    steps = [line for line in result.output.splitlines() if line.startswith("[")]
    assert [s.split()[0] for s in steps] == [f"[{i}/6]" for i in range(1, 7)]
    assert any("pq@4KB (4.0 KB)" in s for s in steps) and any("bruteforce (reference, unbudgeted)" in s for s in steps)
    names = [r["method"] for r in _csv_rows(out / "metrics.csv")]
    assert names == ["pq@4KB", "pq@8KB", "itq@4KB", "itq@8KB", "bruteforce", "bruteforce shrink"]


# -- 12: info and methods say what things are ---------------------------------------------------------------
def test_info_shows_method_parameters_front_end_and_methods_have_descriptions(route_files, tmp_path: Path) -> None:
    db, _ = route_files
    model = tmp_path / "m.npz"
    assert run("train", db, "-o", model, "--method", "btel-f", "--budget", "20KB", "--no-progress").exit_code == 0
    text = run("info", model).output
    assert "method: btel-f — BTELocalizer" in text and "scheme=full" in text
    assert "front end: normalize=l2, whiten=None, delta=None" in text and "total" in text
    lines = run("methods").output.splitlines()
    assert len(lines) == len(METHODS)
    assert all(len(line.split(None, 1)) == 2 for line in lines)  # name, then a description
    assert any(line.startswith("seqslam") and line.endswith("†") for line in lines)


# -- 13: plots have titles, one byte unit style, and a tolerance axis that fits the route --------------------
def test_plots_have_titles_byte_labels_and_a_fitting_tolerance_axis(tmp_path: Path, monkeypatch) -> None:
    import btel.evaluation.plots as plots

    seen = {}
    original_save = plots.run._save

    def keep(fig, path):
        seen[Path(path).name] = fig
        original_save(fig, path)

    for module in (plots.run, plots.sweeps, plots._figure):  # the modules that save the figures
        monkeypatch.setattr(module, "_save", keep)
    route = synthetic_route(n_places=120, dim=16, seed=0)
    jobs = [Job("pq", make_method("pq", budget="3KB")), Job("pq-b", make_method("pq", budget="3.2KB")),
            Job("nn", make_method("bruteforce"), reference=True)]
    results = evaluate_all(jobs, route.map, route.queries)
    RunWriter(tmp_path / "run").finish(results, title="toy: N = 120")
    tolerance_ax = seen["recall_vs_tolerance.png"].axes[0]
    storage_ax = seen["recall_vs_storage.png"].axes[0]
    assert seen["recall_vs_tolerance.png"]._suptitle.get_text() == "toy: N = 120" == storage_ax.get_title()
    assert tolerance_ax.get_xlim()[1] == 20  # 120 places: tolerances up to 10, curve to 20, not 80
    fig = seen["recall_vs_storage.png"]
    fig.canvas.draw()
    labels = [t.get_text() for t in storage_ax.get_xticklabels(minor=False) + storage_ax.get_xticklabels(minor=True)]
    shown = [t for t in labels if t]
    assert shown and all(t.endswith("B") for t in shown), shown  # "5.0 KB", never "3×10⁴"
    legend = [t.get_text() for t in storage_ax.get_legend().get_texts()]
    assert "nn (reference, unbudgeted)" in legend and "budget" in legend
    # Two budgets: one panel each, the reference in both, a method keeps its colour across panels.
    jobs = [Job(f"pq@{b}", make_method("pq", budget=b), series="pq") for b in ("3KB", "6KB")]
    results = evaluate_all(jobs + [Job("nn", make_method("bruteforce"), reference=True)], route.map, route.queries)
    RunWriter(tmp_path / "two").finish(results, title="two budgets")
    panels = seen["recall_vs_tolerance.png"].axes
    assert [ax.get_title() for ax in panels] == ["budget 3.0 KB", "budget 6.0 KB"]
    assert [len(ax.get_lines()) for ax in panels] == [2, 2]
    assert panels[0].get_lines()[0].get_color() == panels[1].get_lines()[0].get_color()
    series = [line.get_label() for line in seen["recall_vs_storage.png"].axes[0].get_lines()]
    assert series[:2] == ["pq", "nn (reference, unbudgeted)"]  # one line through both budgets
    # A long title is wrapped between words, never inside one ("frame-" / "aligned" in the demo's plots).
    long = "synthetic route (seed 0): N = 2000, d = 512; budget 64.0 KB; frame-aligned; " * 2
    RunWriter(tmp_path / "long").finish(results, title=long)
    titles = [t for fig in seen.values() for t in (fig._suptitle.get_text() if fig._suptitle else "",
                                                     *(ax.get_title() for ax in fig.axes))]
    assert any("\n" in t for t in titles) and not any("-\n" in t for t in titles)


def test_failed_rows_in_the_table_say_why() -> None:
    rows = [EvaluationResult.not_measured("itq", "does not fit", "budget too small …", budget=5000,
                                          minimum_bytes=19208)]
    assert "needs ≥ 19.2 KB (budget 5.0 KB)" in format_table(rows)


# -- 7: one name per metric in the experiments too; titles from the run itself -----------------------------
def test_experiment_lines_and_plot_titles_name_metrics_direction_and_budget(tmp_path: Path, monkeypatch) -> None:
    import btel.experiments.accuracy as accuracy
    from btel.experiments import ExperimentRun, describe_row
    from btel.evaluation.records import EvaluationResult

    rows = [{"method": m, "n_places": 300, "budget": None if m == "bruteforce" else 50_000, "nbytes": 1000,
             "direction": d, "status": "ok", "uses_query_sequence": m == "seqslam", "recall@0": 0.1,
             "recall@10": 0.2, "recall@20": 0.3, "R@1": 0.1, "R@10": 0.4}
            for d in ("summer→winter", "winter→summer") for m in ("btel-c", "seqslam", "bruteforce")]
    records = [EvaluationResult.from_row(r) for r in rows]
    lines = [describe_row(r) for r in records]
    assert lines[0].startswith("btel-c [summer→winter]") and lines[3].startswith("btel-c [winter→summer]")
    assert lines[1].startswith("seqslam † [summer→winter]")
    assert "recall@0=0.100" in lines[0] and "R@1=0.100" in lines[0] and "R@10=0.400" in lines[0]
    assert " R@0=" not in lines[0] and " R@20=" not in lines[0]  # R@ is only ever the ranked metric

    titles = []
    monkeypatch.setattr(accuracy, "plot_curves", lambda curves, path, **kw: titles.append((list(curves), kw["title"])))
    curves = {f"{r['method']} {r['direction']}": [0.1, 0.2] for r in rows}
    accuracy.plot(ExperimentRun("accuracy", records, tmp_path, curves), tmp_path)
    assert len(titles) == 2 and all("≤ 50.0 KB" in t and "N = 300" in t and "2 MB" not in t for _, t in titles)
    assert "seqslam † query sequence" in titles[0][0] and "bruteforce (reference, unbudgeted)" in titles[0][0]


def test_evaluate_reports_r_at_20_and_pr_by_default(tmp_path: Path) -> None:
    rng = np.random.default_rng(0)
    X = rng.standard_normal((120, 16)).astype(np.float32)
    np.save(tmp_path / "db.npy", X)
    np.save(tmp_path / "q.npy", X + 0.3 * rng.standard_normal(X.shape).astype(np.float32))
    out = tmp_path / "run"
    result = run("evaluate", "--db", tmp_path / "db.npy", "--queries", tmp_path / "q.npy", "--methods", "pq",
                 "--budget", "5KB", "--out", out, "--no-progress")
    assert result.exit_code == 0, result.output
    assert "R@20" in result.output and "AUC-PR" in result.output and "R@100%P" in result.output
    # VPR-Bench's AUC-PR counts correct matches only: the note says so (btel-c at R@1 0.05 scored 0.52 in the demo).
    assert "a method right on few queries can still score high" in " ".join(result.output.split())
    metrics = json.loads((out / "metrics.json").read_text())
    for row in metrics["results"]:
        assert set(row["recall_at_k"]) == {"1", "5", "10", "20"}
        assert 0 <= row["auc_pr_vpr_tutorial"] <= row["recall_at_k"]["1"] and 0 <= row["auc_pr_vpr_bench"] <= 1
        assert 0 <= row["recall_at_100_precision"] <= 1
        assert row["query_latency_s"] > 0 and row["n_threads"] >= 1
    assert {"auc_pr_vpr_bench", "auc_pr_vpr_tutorial"} <= set((out / "metrics.csv").read_text().splitlines()[0].split(","))
    assert (out / "precision_recall.png").is_file()


def test_ctrl_c_exits_130_with_plots_and_resume_skips_the_rows_done(tmp_path: Path, monkeypatch) -> None:
    import btel.evaluation.batch as ev

    route = synthetic_route(n_places=120, dim=16, seed=1)
    np.save(tmp_path / "db.npy", route.map)
    np.save(tmp_path / "q.npy", route.queries)
    real = ev.measure
    calls: list[str] = []

    def interrupted_at_itq(method, *args, **kwargs):
        calls.append(kwargs["name"])
        if kwargs["name"] == "itq":
            raise KeyboardInterrupt
        return real(method, *args, **kwargs)

    monkeypatch.setattr(ev, "measure", interrupted_at_itq)
    out = tmp_path / "run"
    args = ["evaluate", "--db", tmp_path / "db.npy", "--queries", tmp_path / "q.npy", "--methods", "pq,itq,btel-c",
            "--budget", "4KB", "--no-progress"]
    result = run(*args, "--out", out)
    assert result.exit_code == 130, result.output
    assert (out / "recall_vs_tolerance.png").is_file()  # the partial run's plots
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["run"]["complete"] is False
    assert {r["name"]: r["status"] for r in metrics["results"]} == {
        "pq": "ok", "itq": "not run", "btel-c": "not run", "bruteforce": "not run", "bruteforce shrink": "not run"}
    pq_predictions = (out / "predictions_pq.csv").read_text()

    monkeypatch.setattr(ev, "measure",
                        lambda method, *a, **kw: (calls.append(kw["name"]), real(method, *a, **kw))[1])
    calls.clear()
    # Other queries than the run's: refused, before anything is fitted.
    np.save(tmp_path / "other.npy", route.queries[::-1].copy())
    wrong = run(*[a if a != tmp_path / "q.npy" else tmp_path / "other.npy" for a in args], "--resume", out)
    assert wrong.exit_code == 2 and "this run was started with --queries" in wrong.output and calls == []
    result = run(*args, "--resume", out)
    assert result.exit_code == 0, result.output
    assert "resuming" in result.output and "1 of 5 rows done (pq)" in result.output
    assert calls == ["itq", "btel-c", "bruteforce", "bruteforce shrink"]  # pq is not run again
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["run"]["complete"] is True
    assert [r["status"] for r in metrics["results"]] == ["ok"] * 5
    assert (out / "predictions_pq.csv").read_text() == pq_predictions


def test_a_run_of_saved_models_is_titled_as_such(tmp_path: Path, monkeypatch) -> None:
    import btel.evaluation.plots as plots

    route = synthetic_route(n_places=80, dim=16, seed=2)
    np.save(tmp_path / "db.npy", route.map)
    np.save(tmp_path / "q.npy", route.queries)
    assert run("train", tmp_path / "db.npy", "-o", tmp_path / "m.npz", "--method", "pq", "--budget", "4KB").exit_code == 0
    titles: list[str] = []
    real = plots.plot_run
    monkeypatch.setattr(plots, "plot_run", lambda *a, **kw: (titles.append(kw["title"]), real(*a, **kw))[1])
    result = run("evaluate", "--model", tmp_path / "m.npz", "--queries", tmp_path / "q.npy", "--out", tmp_path / "r",
                 "--no-progress")
    assert result.exit_code == 0, result.output
    assert titles and "saved models" in titles[0] and "budget none" not in titles[0]


@pytest.mark.realdata
@pytest.mark.parametrize("order", ["route", "independent"])
def test_plots_of_independent_queries_do_not_speak_of_frames(order: str, gardenspoint_netvlad, tmp_path: Path,
                                                             monkeypatch: pytest.MonkeyPatch) -> None:
    """Issue 23: with --query-order independent the plots said "recall within t frames"."""
    import matplotlib.text

    import btel.evaluation.plots

    texts: dict[str, list[str]] = {}
    save = btel.evaluation.plots.run._save

    def recording_save(fig, path):  # every word drawn in every figure of the run
        texts[Path(path).name] = [t.get_text() for t in fig.findobj(matplotlib.text.Text)]
        save(fig, path)

    for module in (btel.evaluation.plots.run, btel.evaluation.plots.sweeps, btel.evaluation.plots._figure):  # the modules that save the figures
        monkeypatch.setattr(module, "_save", recording_save)
    X, Q = gardenspoint_netvlad
    db, q = tmp_path / "db.npy", tmp_path / "q.npy"
    np.save(db, X[:100])
    np.save(q, Q[:100])
    result = run("evaluate", "--db", db, "--queries", q, "--methods", "pq", "--budget", "8KB", "--query-order", order,
                 "--no-progress", "--out", tmp_path / "run")
    assert result.exit_code == 0, result.output
    assert {"recall_vs_tolerance.png", "recall_vs_storage.png"} <= set(texts)
    words = " ".join(t for name in ("recall_vs_tolerance.png", "recall_vs_storage.png") for t in texts[name])
    if order == "route":
        assert "tolerance t (frames)" in words and "within 10 frames" in words
    else:
        assert "frames" not in words
        assert "tolerance t (map places)" in words and "within 10 map places" in words


def test_a_descriptor_matrix_given_as_model_is_named_as_one(route_files, tmp_path: Path) -> None:
    db, q = route_files
    result = CliRunner().invoke(main, ["evaluate", "--model", str(db), "--queries", str(q), "--out", str(tmp_path / "r")])
    assert result.exit_code == 2
    assert "looks like a descriptor matrix (200 × 32 float32), not a model" in result.output
    assert "give this matrix as --db" in result.output and not (tmp_path / "r").exists()
    (tmp_path / "junk.npz").write_bytes(b"not a zip")  # not a matrix either: the model file's own error stands
    result = CliRunner().invoke(main, ["evaluate", "--model", str(tmp_path / "junk.npz"), "--queries", str(q),
                                       "--out", str(tmp_path / "r")])
    assert result.exit_code == 2 and "descriptor matrix" not in result.output


def test_saved_models_of_one_file_name_are_told_apart_by_their_folders(route_files, tmp_path: Path) -> None:
    """Two runs' ``lsh.npz`` (or a saved ``bruteforce.npz`` beside the fitted reference) are rows named by as much
    of their folder path as tells them apart; the same file given twice is refused before the run folder exists."""
    db, q = route_files
    for folder, budget in (("a", "4KB"), ("b", "2KB")):
        (tmp_path / folder).mkdir()
        assert run("train", db, "-o", tmp_path / folder / "lsh.npz", "--method", "lsh", "--budget", budget).exit_code == 0
    assert run("train", db, "-o", tmp_path / "a" / "bruteforce.npz", "--method", "bruteforce").exit_code == 0
    result = run("evaluate", "--db", db, "--methods", "pq", "--budget", "4KB", "--model", tmp_path / "a" / "lsh.npz",
                 "--model", tmp_path / "b" / "lsh.npz", "--model", tmp_path / "a" / "bruteforce.npz", "--queries", q,
                 "--out", tmp_path / "run", "--no-progress")
    assert result.exit_code == 0, result.output
    names = [r["name"] for r in json.loads((tmp_path / "run" / "metrics.json").read_text())["results"]]
    assert names[:3] == ["a/lsh", "b/lsh", "a/bruteforce"] and "bruteforce" in names[3:]
    twice = CliRunner().invoke(main, ["evaluate", "--model", str(tmp_path / "a" / "lsh.npz"), "--model",
                                      str(tmp_path / "a" / ".." / "a" / "lsh.npz"), "--queries", str(q), "--out",
                                      str(tmp_path / "run2")])
    assert twice.exit_code == 2 and "given twice" in twice.output and not (tmp_path / "run2").exists()


def test_evaluate_reads_a_folder_of_shards_as_train_does(route_files, tmp_path: Path) -> None:
    """``--db FOLDER`` of .npy shards: the same rows as the whole matrix (large-maps guide)."""
    db, q = route_files
    X = np.load(db)
    (tmp_path / "shards").mkdir()
    for i in range(4):
        np.save(tmp_path / "shards" / f"shard_{i}.npy", X[i * 50:(i + 1) * 50])
    recalls = []
    for source, out in ((db, "whole"), (tmp_path / "shards", "sharded")):
        result = run("evaluate", "--db", source, "--queries", q, "--methods", "lsh", "--budget", "2KB",
                     "--out", tmp_path / out, "--no-progress")
        assert result.exit_code == 0, result.output
        recalls.append([(r["recall_curve"], r["recall_at_k"]) for r in json.loads((tmp_path / out / "metrics.json").read_text())["results"]])
    assert recalls[0] == recalls[1]


def test_metrics_csv_says_what_each_auto_row_ran(route_files, tmp_path: Path) -> None:
    """metrics.json recorded auto's choice; metrics.csv had only 'auto@16KB'."""
    db, q = route_files
    result = run("evaluate", "--db", db, "--queries", q, "--methods", "auto,pq", "--budget", "2KB,8KB", "--out",
                 tmp_path / "run", "--no-progress")
    assert result.exit_code == 0, result.output
    rows = _csv_rows(tmp_path / "run" / "metrics.csv")
    recorded = {r["name"]: r["chosen_method"] for r in json.loads((tmp_path / "run" / "metrics.json").read_text())["results"]}
    assert {r["method"]: r["chosen_method"] for r in rows} == {k: v or "" for k, v in recorded.items()}
    assert all(r["chosen_method"] for r in rows if r["method"].startswith("auto"))
    assert not any(r["chosen_method"] for r in rows if not r["method"].startswith("auto"))


def test_saved_model_names_keep_their_inner_dots_and_clash_as_file_names_up_front(route_files, tmp_path: Path) -> None:
    """lsh.v1.npz and lsh.v2.npz were both 'lsh' (then refused as indistinct); a/lsh.npz and b/lsh.npz beside
    a-lsh.npz ran every model and failed at the end, when two predictions files were to share a name."""
    db, q = route_files
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    for name in ("lsh.v1.npz", "lsh.v2.npz", "a/lsh.npz", "b/lsh.npz", "a-lsh.npz"):
        assert run("train", db, "-o", tmp_path / name, "--method", "lsh", "--budget", "2KB").exit_code == 0
    result = run("evaluate", "--model", tmp_path / "lsh.v1.npz", "--model", tmp_path / "lsh.v2.npz", "--queries", q,
                 "--out", tmp_path / "run", "--no-progress")
    assert result.exit_code == 0, result.output
    assert [r["name"] for r in json.loads((tmp_path / "run" / "metrics.json").read_text())["results"]] == [
        "lsh.v1", "lsh.v2"]
    clash = CliRunner().invoke(main, ["evaluate", "--model", str(tmp_path / "a" / "lsh.npz"), "--model",
                                      str(tmp_path / "b" / "lsh.npz"), "--model", str(tmp_path / "a-lsh.npz"),
                                      "--queries", str(q), "--out", str(tmp_path / "run2")])
    assert clash.exit_code == 2 and "would name the same row" in clash.output and not (tmp_path / "run2").exists()


def test_an_evaluation_without_a_budget_says_so(tmp_path: Path) -> None:
    """pq fitted unbudgeted (267 KB on a tester's map) with no word of it; train said so, evaluate did not."""
    from btel.datasets import synthetic_route

    route = synthetic_route(200, 16, seed=0)
    np.save(tmp_path / "db.npy", route.map)
    np.save(tmp_path / "q.npy", route.queries)
    args = ["evaluate", "--db", str(tmp_path / "db.npy"), "--queries", str(tmp_path / "q.npy"), "--methods", "pq",
            "--no-progress", "--no-reference"]
    result = CliRunner().invoke(main, [*args, "--out", str(tmp_path / "a")])
    assert result.exit_code == 0 and "note: no --budget: every method is as large as it needs" in result.output
    result = CliRunner().invoke(main, [*args, "--budget", "4KB", "--out", str(tmp_path / "b")])
    assert result.exit_code == 0 and "no --budget" not in result.output
