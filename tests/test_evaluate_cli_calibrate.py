"""`btel evaluate --calibrate QUERIES --calibrate-truth GT` (issue 37): the methods whose fit takes labelled
queries choose on them, through the one measurement path; the calibration table lands in metrics.json,
the console and calibration.md; no calibration query is stored."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from click.testing import CliRunner

from btel.cli import main
from btel.datasets import synthetic_route
from btel.evaluation import Job, evaluate_all
from btel.evaluation.inputs import calibrate_jobs, takes_calibration
from btel.evaluation.tables import calibration_markdown, format_calibration
from btel.exceptions import InvalidParameterError
from btel.methods import make_method

N = 120


def run(*args: object) -> Any:
    return CliRunner().invoke(main, [str(a) for a in args], catch_exceptions=False)


@pytest.fixture(scope="module")
def files(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """A route map; its queries split: the even ones label the calibration, the odd ones are evaluated."""
    d = tmp_path_factory.mktemp("calibrate")
    r = synthetic_route(N, 16, condition_shift=1.5, noise=0.4, seed=5)
    places = np.arange(N)
    arrays = {"db": r.map, "q_even": r.queries[::2], "q_odd": r.queries[1::2], "t_even": places[::2],
              "t_odd": places[1::2], "t_short": places[:7], "narrow": r.queries[::2, :8],
              "q_one": r.queries[:1], "t_one": places[:1],
              "nan": np.where(places[::2, None] == 4, np.nan, r.queries[::2])}
    for name, a in arrays.items():
        np.save(d / f"{name}.npy", a)
    return {name: d / f"{name}.npy" for name in arrays} | {"dir": d}


def _leaves(node: Any) -> list[Any]:
    """Every list inside a JSON tree (to find one as long as the calibration set)."""
    if isinstance(node, dict):
        return [x for v in node.values() for x in _leaves(v)]
    if isinstance(node, list):
        return [node] + [x for v in node for x in _leaves(v)]
    return []


def test_auto_is_calibrated_the_others_are_not_and_the_table_is_in_the_run(files, tmp_path: Path) -> None:
    out = tmp_path / "run"
    result = run("evaluate", "--db", files["db"], "--queries", files["q_odd"], "--ground-truth",
                 files["t_odd"], "--methods", "auto,lsh", "--budget", "800B", "--calibrate", files["q_even"],
                 "--calibrate-truth", files["t_even"], "--calibrate-tolerance", "1", "--no-progress",
                 "--out", out)
    assert result.exit_code == 0, result.output
    # said once, on stderr: which rows fitted on the map alone; no warning (the queries are held out)
    notes = [line for line in result.stderr.splitlines() if line.startswith("--calibrate:")]
    assert notes == ["--calibrate: auto chosen on the 60 labelled queries; lsh, bruteforce, bruteforce "
                     "shrink fitted on the map alone (no calibration in their fit, or saved)."]
    assert "optimistic" not in result.output
    payload = json.loads((out / "metrics.json").read_text())
    rows = {r["name"]: r for r in payload["results"]}
    c = rows["auto"]["choice"]["calibration"]
    assert c["n_queries"] == N // 2 and c["tolerance"] == 1 and isinstance(c["switched"], bool)
    scored = [e for e in c["table"] if e["status"] == "ok"]
    assert len(scored) >= 5 and {"lsh", "btel-codes periodic"} <= {e["candidate"] for e in scored}
    assert all(0 <= e["score"] <= 1 for e in scored)
    compared = [e for e in scored if e["candidate"] != c["map_only"]]
    assert compared and all({"difference", "p_adjusted", "queries_needed"} <= set(e) for e in compared)
    assert rows["auto"]["settings"] == {"calibration_tolerance": 1}
    assert rows["lsh"]["choice"] is None and rows["bruteforce"]["choice"] is None
    meta = payload["run"]["extra"]["calibration"]
    assert meta["queries"] == str(files["q_even"].resolve()) and meta["n_queries"] == N // 2
    assert meta["calibrated"] == ["auto"]
    assert meta["not_calibrated"] == ["lsh", "bruteforce", "bruteforce shrink"]
    assert not any(len(x) >= N // 2 for x in _leaves(rows["auto"]["choice"]))  # scalars, no per-query list
    # the run's text report (console) and calibration.md carry the table
    assert f"auto — calibration: {N // 2} labelled queries, correct when within 1 place of the true place" in result.stdout
    md = (out / "calibration.md").read_text()
    assert md.startswith("# Calibration") and "## auto" in md and "## lsh" not in md
    assert f"map-only pick {c['map_only']}" in md and all(e["candidate"] in md for e in c["table"])


def test_calibrating_on_the_evaluated_queries_warns_the_evaluation_is_optimistic(files, tmp_path) -> None:
    result = run("evaluate", "--db", files["db"], "--queries", files["q_even"], "--ground-truth",
                 files["t_even"], "--methods", "auto", "--no-reference", "--budget", "800B", "--calibrate",
                 files["q_even"], "--calibrate-truth", files["t_even"], "--no-progress", "--out",
                 tmp_path / "run")
    assert result.exit_code == 0, result.output
    warned = [line for line in result.stderr.splitlines() if "optimistic" in line]
    assert warned == [f"Warning: {N // 2} of the {N // 2} evaluated queries are calibration queries: the "
                      "evaluation is then optimistic; calibrate on a held-out part."]
    assert "--calibrate:" not in result.stderr  # every row was calibrated: nothing to say


def test_calibration_ground_truth_utm_from_the_image_names(files, tmp_path: Path) -> None:
    """--calibrate-truth utm: positives within --positive-dist-threshold metres (place i at 10·i m east)."""
    for stem, src, east in (("db", "db", np.arange(N) * 10.0), ("cal", "q_even", np.arange(0, N, 2) * 10.0 + 1)):
        np.save(tmp_path / f"{stem}.npy", np.load(files[src]))
        images = [[f"@{500000 + e:.2f}@4000000.00@55@H@@.jpg", None] for e in east]
        (tmp_path / f"{stem}.npy.json").write_text(json.dumps({"images": images}))
    out = tmp_path / "run"
    result = run("evaluate", "--db", tmp_path / "db.npy", "--queries", files["q_odd"], "--ground-truth",
                 files["t_odd"], "--methods", "auto", "--no-reference", "--budget", "800B", "--calibrate",
                 tmp_path / "cal.npy", "--calibrate-truth", "utm", "--positive-dist-threshold", "5",
                 "--no-progress", "--out", out)
    assert result.exit_code == 0, result.output
    payload = json.loads((out / "metrics.json").read_text())
    assert payload["run"]["extra"]["calibration"]["ground_truth"] == {"source": "UTM in image names",
                                                                      "rule": "positives within 5 m"}
    assert payload["run"]["extra"]["ground_truth"]["source"] == str(files["t_odd"].resolve())
    c = payload["results"][0]["choice"]["calibration"]
    assert c["n_queries"] == N // 2 and sum(e["status"] == "ok" for e in c["table"]) >= 5


@pytest.mark.parametrize("args, message", [
    (["--model", "{model}", "--calibrate", "{q_even}"], "saved --model files are fitted already"),
    (["--db", "{db}", "--calibrate-truth", "{t_even}"], "--calibrate-truth applies with --calibrate QUERIES"),
    (["--db", "{db}", "--calibrate-tolerance", "1"], "--calibrate-tolerance applies with --calibrate QUERIES"),
    (["--db", "{db}", "--methods", "lsh,pq", "--calibrate", "{q_even}"], "Add auto to --methods"),
    (["--db", "{db}", "--methods", "auto", "--param", "auto:calibration_tolerance=2", "--calibrate",
      "{q_even}", "--calibrate-truth", "{t_even}", "--calibrate-tolerance", "1"], "set twice"),
    (["--db", "{db}", "--methods", "auto", "--calibrate", "{q_even}", "--calibrate-truth", "{t_short}"],
     "--calibrate-truth:"),
    (["--db", "{db}", "--calibrate", "{narrow}", "--calibrate-truth", "{t_even}"], "have 8 dims but the map"),
    (["--db", "{db}", "--calibrate", "{nan}", "--calibrate-truth", "{t_even}"], "NaN or infinite values"),
    (["--db", "{db}", "--calibrate", "{q_one}", "--calibrate-truth", "{t_one}"], "at least 2 labelled queries"),
    (["--db", "{db}", "--calibrate", "{q_even}", "--calibrate-truth", "{t_even}", "--positive-dist-threshold",
      "10"], "--positive-dist-threshold applies to it (and --calibrate-truth utm) only"),
])
def test_calibration_usage_errors_exit_2_naming_the_fix(files, args: list[str], message: str) -> None:
    model = files["dir"] / "m.npz"
    if not model.exists():
        make_method("lsh", budget="1KB").fit(np.load(files["db"])).save(model)
    filled = [a.format(model=model, **{k: v for k, v in files.items()}) for a in args]
    result = run("evaluate", "--queries", files["q_odd"], "--ground-truth", files["t_odd"], "--budget",
                 "800B", "--no-progress", "--out", files["dir"] / "never", *filled)
    assert result.exit_code == 2, result.output
    assert message in result.output and "Traceback" not in result.output
    assert not (files["dir"] / "never").exists()


class _Recorder:
    """Not a btel method: a fit that takes calibration, and one answer."""

    def __init__(self) -> None:
        self.seen: Any = None

    def fit(self, X: np.ndarray, calibration: Any = None) -> "_Recorder":
        self.seen, self.n_places_ = calibration, X.shape[0]
        return self

    def predict(self, Q: np.ndarray) -> np.ndarray:
        return np.zeros(len(Q), dtype=np.int64)


def test_the_method_is_asked_not_named_and_the_fit_goes_through_measure() -> None:
    """calibrate_jobs reads fit's signature (an object outside btel is calibrated, lsh is not), and
    evaluate_all hands the calibration to the fit (measure's timed_fit)."""
    X = np.random.default_rng(0).standard_normal((30, 8)).astype(np.float32)
    calibration = (X[:10], np.arange(10))
    assert takes_calibration(make_method("auto")) and not takes_calibration(make_method("lsh"))
    jobs = [Job("mine", _Recorder()), Job("lsh", make_method("lsh", budget="1KB")),
            Job("saved", make_method("lsh", budget="1KB").fit(X), fit=False)]
    assert calibrate_jobs(jobs, calibration, tolerance=3) == ["lsh", "saved"]
    assert jobs[0].fit_params == {"calibration": calibration} and jobs[1].fit_params is None
    assert jobs[0].settings is None  # no calibration_tolerance parameter: nothing set
    rows = evaluate_all(jobs, X, X, ks=())
    assert [r.status for r in rows] == ["ok"] * 3 and jobs[0].method.seen is calibration
    assert format_calibration(rows) == calibration_markdown(rows) == ""  # no row chose: no calibration.md
    auto = Job("auto", make_method("auto", budget="1KB", calibration_tolerance=2),
               settings={"calibration_tolerance": 2})
    with pytest.raises(InvalidParameterError, match="set twice"):
        calibrate_jobs([auto], calibration, tolerance=1)


@pytest.mark.realdata
def test_gardens_point_calibrated_on_even_night_queries_evaluated_on_the_odd(gardenspoint_netvlad,
                                                                            tmp_path: Path) -> None:
    """Map = day; calibrate on the even night frames, evaluate the odd ones (frame-aligned truth)."""
    day, night = gardenspoint_netvlad
    places = np.arange(len(day))
    for name, a in {"day": day, "even": night[::2], "odd": night[1::2], "t_even": places[::2],
                    "t_odd": places[1::2]}.items():
        np.save(tmp_path / f"{name}.npy", a)
    out = tmp_path / "run"
    result = run("evaluate", "--db", tmp_path / "day.npy", "--queries", tmp_path / "odd.npy",
                 "--ground-truth", tmp_path / "t_odd.npy", "--methods", "auto", "--budget", "4KB",
                 "--calibrate", tmp_path / "even.npy", "--calibrate-truth", tmp_path / "t_even.npy",
                 "--calibrate-tolerance", "2", "--no-reference", "--no-progress", "--out", out)
    assert result.exit_code == 0, result.output
    payload = json.loads((out / "metrics.json").read_text())
    auto = next(r for r in payload["results"] if r["name"] == "auto")
    c = auto["choice"]["calibration"]
    assert c["n_queries"] == 100 and c["tolerance"] == 2
    scored = {e["candidate"]: e for e in c["table"] if e["status"] == "ok"}
    assert {"lsh", "lsh centred", "lsh shrink", "btel-codes periodic", "rabitq"} <= set(scored)
    chosen = scored[c["chosen"]]
    if c["switched"]:
        assert chosen["p_adjusted"] < c["alpha"] and chosen["difference"] > 0
    # the held-out (odd) queries agree with the calibration score of the chosen candidate within noise
    assert abs(auto["recall"]["2"] - chosen["score"]) < 0.15
    assert "## auto" in (out / "calibration.md").read_text()
    # nothing of the calibration queries is kept: no array file, no list as long as the calibration set
    assert not list(out.glob("*.np*"))
    assert not any(len(x) >= 100 for x in _leaves(auto["choice"]))


def test_a_calibrated_train_logged_to_a_file_says_how_far_it_got(files, tmp_path: Path, monkeypatch) -> None:
    """stderr no terminal (a log, a batch job): a 7-minute calibration printed one line, then nothing until done."""
    from btel.core import progress

    monkeypatch.setattr(progress, "LINE_EVERY_SECONDS", 0.0)  # a line per fit: every one of them is seen
    result = run("train", files["db"], "-o", tmp_path / "m.npz", "--method", "auto", "--budget", "800B",
                 "--calibrate", files["q_even"], "--calibrate-truth", files["t_even"], "--calibrate-tolerance", "1")
    assert result.exit_code == 0, result.output
    lines = [line for line in result.stderr.splitlines() if line.startswith("calibrating auto: ")]
    counts = [tuple(map(int, line.split()[2].split("/"))) for line in lines]
    total = counts[-1][1]
    assert total > 3 and [done for done, _ in counts] == list(range(1, total + 1))
    assert "(now " in lines[0] and lines[-1].startswith(f"calibrating auto: {total}/{total} fits done, 0:")
    # --no-progress: none of them
    quiet = run("train", files["db"], "-o", tmp_path / "q.npz", "--method", "auto", "--budget", "800B", "--no-progress",
                "--calibrate", files["q_even"], "--calibrate-truth", files["t_even"], "--calibrate-tolerance", "1")
    assert quiet.exit_code == 0 and "calibrating auto: " not in quiet.stderr


def test_line_progress_speaks_at_most_every_so_often_and_once_at_the_end() -> None:
    import io

    from btel.core.progress import LineProgress

    out = io.StringIO()
    bar = LineProgress(5, "working", "step", every=3600.0, file=out)
    for _ in range(5):
        bar.update(1)
    bar.close()
    assert out.getvalue() == ""  # fast work: nothing to say
    bar = LineProgress(3, "working", "step", every=0.0, file=out)
    bar.set_postfix_str("pq")
    bar.update(1)
    bar.update(2)
    bar.close()
    assert out.getvalue().splitlines() == ["working: 1/3 steps done (now pq), 0:00 elapsed",
                                           "working: 3/3 steps done, 0:00 elapsed"]


def test_the_calibration_table_shows_each_candidates_answer_time(files, tmp_path: Path) -> None:
    """The calibrated pick on Nordland at 1 MB (PQ) answered in 4,262 µs a query against the map-only LSH's 303,
    and the table gave no speed to weigh beside the scores."""
    from btel import load

    result = run("train", files["db"], "-o", tmp_path / "m.npz", "--method", "auto", "--budget", "800B",
                 "--no-progress", "--calibrate", files["q_even"], "--calibrate-truth", files["t_even"],
                 "--calibrate-tolerance", "1")
    assert result.exit_code == 0, result.output
    table = load(tmp_path / "m.npz").choice_["calibration"]["table"]
    timed = [e for e in table if e["status"] == "ok"]
    assert timed and all(e["query_us"] > 0 for e in timed)
    shown = run("info", tmp_path / "m.npz").output
    assert "µs/q" in shown and "µs/q: its mean answer" in shown
    row = next(line for line in shown.splitlines() if line.strip().startswith(timed[0]["candidate"]))
    assert f"{timed[0]['query_us']:.1f}" in row
