"""The `btel` command line, end to end, through click's runner (same code path as the console script)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from btel.cli import main
from btel.evaluation.runs import recompute_recall_from_csv


def run(*args: str) -> "click.testing.Result":  # noqa: F821
    result = CliRunner().invoke(main, [str(a) for a in args], catch_exceptions=False)
    return result


@pytest.fixture()
def small_pair(tmp_path: Path) -> tuple[Path, Path]:
    rng = np.random.default_rng(0)
    X = rng.standard_normal((300, 64)).astype(np.float32)
    Q = X + 0.05 * rng.standard_normal(X.shape).astype(np.float32)
    np.save(tmp_path / "db.npy", X)
    np.save(tmp_path / "q.npy", Q)
    return tmp_path / "db.npy", tmp_path / "q.npy"


@pytest.mark.parametrize("command", [[], ["demo"], ["extract"], ["train"], ["localize"], ["evaluate"], ["info"]])
def test_help_everywhere(command: list[str]) -> None:
    result = run(*command, "--help")
    assert result.exit_code == 0
    assert "Usage:" in result.output


def test_train_localize_info(small_pair, tmp_path: Path) -> None:
    db, q = small_pair
    model = tmp_path / "m.btel.npz"
    result = run("train", db, "-o", model, "--method", "btel-c", "--budget", "5KB", "--n-features", "16")
    assert result.exit_code == 0, result.output
    assert "storage breakdown" in result.output and "total" in result.output
    preds = tmp_path / "p.csv"
    result = run("localize", model, q, "-o", preds, "--sequence-filter", "3")
    assert result.exit_code == 0, result.output
    rows = preds.read_text().splitlines()
    assert rows[0] == "query,prediction" and len(rows) == 301
    values = np.array([int(r.split(",")[1]) for r in rows[1:]])
    assert values.min() >= 0 and values.max() < 300
    result = run("info", model)
    assert result.exit_code == 0 and "N = 300" in result.output


@pytest.mark.parametrize(
    "args, message",
    [
        (["train", "missing.npy", "-o", "m.npz"], "missing.npy"),
        (["localize", "missing.npz", "q.npy", "-o", "p.csv"], "does not exist"),
        (["train", "DB", "-o", "m.npz", "--budget", "10B"], "too small"),
        (["train", "DB", "-o", "m.npz", "--budget", "lots"], "not understood"),
        (["localize", "DB", "Q", "-o", "p.csv"], "looks like a descriptor matrix"),  # arguments swapped
        (["extract", "no-such-folder", "-o", "x.npy"], "no-such-folder"),
        (["evaluate", "--queries", "Q", "--out", "run"], "--db"),
    ],
)
def test_errors_are_one_line_with_nonzero_exit(args, message, small_pair, tmp_path: Path, monkeypatch) -> None:
    db, q = small_pair
    monkeypatch.chdir(tmp_path)
    args = [str(db) if a == "DB" else str(q) if a == "Q" else a for a in args]
    result = CliRunner().invoke(main, args)
    assert result.exit_code != 0
    assert "Traceback" not in result.output
    assert message in result.output
    assert result.output.strip().count("\n") <= 4  # a usage line at most, then the error


def test_demo_runs_and_writes_a_run_folder(tmp_path: Path) -> None:
    out = tmp_path / "demo"
    result = run("demo", "--places", "300", "--dim", "64", "--methods", "btel-c,btel-r", "--budget", "20KB",
                 "--out", out)
    assert result.exit_code == 0, result.output
    metrics = json.loads((out / "metrics.json").read_text())
    # Brute force is always there, as the unbudgeted reference rows: cosine, and on shrinkage-whitened rows.
    assert [r["name"] for r in metrics["results"]] == ["btel-c", "btel-r", "bruteforce", "bruteforce shrink"]
    assert [r["reference"] for r in metrics["results"]] == [False, False, True, True]
    assert all(r["nbytes"] <= 20_000 for r in metrics["results"] if not r["reference"])
    assert (out / "recall_vs_tolerance.png").stat().st_size > 0


def test_demo_joins_repeated_methods_and_budgets_as_evaluate_does(tmp_path: Path) -> None:
    """`--methods pq --methods lsh --budget 4KB --budget 8KB` fitted lsh at 8KB only (the last of each)."""
    out = tmp_path / "demo"
    result = run("demo", "--places", "150", "--dim", "16", "--methods", "pq", "--methods", "lsh", "--budget", "4KB",
                 "--budget", "8KB", "--no-reference", "--no-progress", "--out", out)
    assert result.exit_code == 0, result.output
    rows = json.loads((out / "metrics.json").read_text())["results"]
    assert [(r["name"], r["budget"]) for r in rows] == [("pq@4KB", 4000), ("pq@8KB", 8000), ("lsh@4KB", 4000),
                                                        ("lsh@8KB", 8000)]


@pytest.mark.realdata
def test_nordland_extract_train_localize_evaluate(nordland_dir: Path, tmp_path: Path) -> None:
    """extract → train → localize → evaluate on real Nordland frames (every 8th, to stay fast)."""
    for season in ("summer", "winter"):
        folder = tmp_path / season
        folder.mkdir()
        for image in sorted((nordland_dir / season).glob("images-*.png"))[::8]:
            (folder / image.name).symlink_to(image)
    db, q, model = tmp_path / "db.npy", tmp_path / "q.npy", tmp_path / "map.btel.npz"
    for folder, out in ((tmp_path / "summer", db), (tmp_path / "winter", q)):
        result = run("extract", folder, "-o", out, "--descriptor", "patchnorm", "--no-progress")
        assert result.exit_code == 0, result.output
    again = run("extract", tmp_path / "summer", "-o", db, "--descriptor", "patchnorm")
    assert "up to date" in again.output  # the cache
    # The queries described over the map descriptors: refused, naming what would be lost.
    before = db.read_bytes()
    wrong = run("extract", tmp_path / "winter", "-o", db, "--descriptor", "patchnorm", "--no-progress")
    assert wrong.exit_code == 2 and "already exists" in wrong.output and "447 images" in wrong.output
    assert "--overwrite" in wrong.output and db.read_bytes() == before
    X = np.load(db)
    assert X.shape == (447, 2048) and np.isfinite(X).all()

    result = run("train", db, "-o", model, "--method", "btel-c", "--budget", "100KB", "--regions", "4", "--seed", "0")
    assert result.exit_code == 0, result.output
    preds = tmp_path / "predictions.csv"
    assert run("localize", model, q, "-o", preds).exit_code == 0
    run_dir = tmp_path / "run"
    result = run("evaluate", "--model", model, "--queries", q, "--out", run_dir)
    assert result.exit_code == 0, result.output

    metrics = json.loads((run_dir / "metrics.json").read_text())
    (entry,) = metrics["results"]
    assert entry["nbytes"] <= 100_000
    recorded = {int(t): v for t, v in entry["recall"].items()}
    # The recall in metrics.json equals a recomputation from the predictions — both the run
    # folder's CSV and the one `btel localize` wrote with the same model.
    assert recompute_recall_from_csv(run_dir / "predictions_map.csv", recorded) == pytest.approx(recorded)
    assert recompute_recall_from_csv(preds, recorded) == pytest.approx(recorded)
    assert metrics["run"]["command"]  # the command line is recorded with the run


def test_train_with_code_options_and_localize_with_hmm_and_top_k(small_pair, tmp_path: Path) -> None:
    db, q = small_pair
    model = tmp_path / "m.btel.npz"
    result = run("train", db, "-o", model, "--method", "btel-c", "--budget", "8KB", "--tolerance", "5", "--code-copies", "2",
                 "--exemplar-radius", "1")
    assert result.exit_code == 0, result.output
    from btel import load

    fitted = load(model)
    assert fitted.block_size == 4 and fitted.code_copies == 2 and fitted.exemplar_radius == 1
    preds = tmp_path / "p.csv"
    result = run("localize", model, q, "-o", preds, "--hmm", "--top-k", "3")
    assert result.exit_code == 0, result.output
    rows = [r.split(",") for r in preds.read_text().splitlines()]
    assert rows[0] == ["query", "prediction", "rank_1", "rank_2", "rank_3"] and len(rows) == 301
    ranked = np.array([[int(v) for v in r[2:]] for r in rows[1:]])
    np.testing.assert_array_equal(ranked, fitted.rank(np.load(q), 3))
    for args, message in ((["--hmm", "--sequence-filter", "3"], "not both"), (["--top-k", "0"], "k")):
        result = run("localize", model, q, "-o", preds, "--overwrite", *args)
        assert result.exit_code != 0 and message in result.output
    result = run("train", db, "-o", model, "--method", "btel-c", "--block-size", "4", "--tolerance", "4")
    assert result.exit_code != 0 and "not both" in result.output
    result = run("train", db, "-o", model, "--method", "pq", "--code-copies", "2")
    assert result.exit_code == 2 and "'code_copies', which pq does not have" in result.output


# -- no file is replaced without --overwrite ----------------------------------------------------------------
def test_train_and_localize_refuse_an_existing_output_without_overwrite(small_pair, tmp_path: Path) -> None:
    db, q = small_pair
    model, preds = tmp_path / "m.npz", tmp_path / "p.csv"
    assert run("train", db, "-o", model, "--budget", "5KB", "--no-progress").exit_code == 0
    before = model.read_bytes()
    result = run("train", db, "-o", model, "--method", "pq", "--budget", "5KB")
    assert result.exit_code == 2 and "already exists" in result.output and "--overwrite" in result.output
    assert model.read_bytes() == before
    assert run("train", db, "-o", model, "--method", "pq", "--budget", "5KB", "--overwrite").exit_code == 0
    assert model.read_bytes() != before
    preds.write_text("mine\n")
    result = run("localize", model, q, "-o", preds)
    assert result.exit_code == 2 and "1 lines" in result.output and preds.read_text() == "mine\n"
    assert run("localize", model, q, "-o", preds, "--overwrite").exit_code == 0
    assert preds.read_text().startswith("query,prediction")


# -- errors in the command line's words -----------------------------------------------------------------------
@pytest.mark.parametrize("args, code, words", [
    (["train", "DB", "-o", "OUT", "--budget", "32"], 2, ["did you mean 32KB?", "32B"]),
    (["evaluate", "--db", "DB", "--queries", "DB", "--budget", "500KB,64", "--out", "OUT"], 2, ["did you mean 64KB?"]),
    (["train", "DB", "-o", "OUT", "--method", "nope"], 2, ["unknown method 'nope'", "btel-c", "pq"]),
    (["evaluate", "--db", "DB", "--queries", "DB", "--methods", "pq,nope", "--out", "OUT"], 2, ["unknown method 'nope'"]),
    (["info", "MISSING"], 2, ["Train one with `btel train DB -o MODEL`"]),
])
def test_errors_speak_cli(args, code, words, small_pair, tmp_path: Path) -> None:
    db, _ = small_pair
    subst = {"DB": str(db), "OUT": str(tmp_path / "out"), "MISSING": str(tmp_path / "missing.npz")}
    result = CliRunner().invoke(main, [subst.get(a, a) for a in args])
    assert result.exit_code == code, result.output
    assert "Traceback" not in result.output
    for w in words:
        assert w in result.output
    for python_word in ("BTELocalizer.fit", "fit_on=", "key="):
        assert python_word not in result.output
    assert not (tmp_path / "out").exists()


def test_a_unitless_budget_from_1000_up_is_bytes(small_pair, tmp_path: Path) -> None:
    db, _ = small_pair
    result = run("train", db, "-o", tmp_path / "m.npz", "--budget", "5000", "--no-progress")
    assert result.exit_code == 0, result.output


def test_cli_message_rewrites_library_phrases() -> None:
    from btel.cli._errors import cli_message

    assert cli_message("descriptor 'densevlad' learns from map images: pass fit_on=<map images> (…)") == \
        "descriptor 'densevlad' learns from map images: pass --fit-on MAP_IMAGES_DIR (…)"
    assert "--param dtype=float16" in cli_message("Raise the budget, use dtype='float16', or fewer regions.")
    assert cli_message("x.npz holds 2 arrays (a, b); choose one: x.npz:a on the command line, key='a' in Python.") \
        == "x.npz holds 2 arrays (a, b); choose one: x.npz:a."


# -- --param: any parameter of any method --------------------------------------------------------------
@pytest.mark.parametrize("text, value", [("3", 3), ("0.5", 0.5), ("true", True), ("null", None), ('"x"', "x"),
                                         ("[1, 2]", [1, 2]), ("auto", "auto"), ("float16", "float16"),
                                         ("NaN", "NaN"), ("", ""), ("tcp://host:8786", "tcp://host:8786")])
def test_param_values_are_json_literals_or_text(text: str, value: object) -> None:
    from btel.cli._params import _param_value

    assert _param_value(text) == value and type(_param_value(text)) is type(value)


def test_train_help_shows_param_and_hides_the_old_method_flags() -> None:
    from btel.cli.train import ALIASES

    text = " ".join(run("train", "--help").output.split())
    assert "--param NAME=VALUE" in text and "--budget" in text and "--seed" in text
    assert not [flag for flag in [*ALIASES, "tolerance"] if f"--{flag} " in text]
    assert "still work as aliases of --param" in text


def test_train_param_fills_the_same_parameters_as_the_shortcuts(small_pair, tmp_path: Path) -> None:
    from btel import load

    db, _ = small_pair
    a, b = tmp_path / "a.npz", tmp_path / "b.npz"
    assert run("train", db, "-o", a, "--method", "btel-c", "--budget", "8KB", "--n-features", "16", "--dtype", "float16", "--seed", "1",
               "--no-progress").exit_code == 0
    result = run("train", db, "-o", b, "--method", "btel-c", "--param", "budget=8KB", "--param", "n_features=16", "--param", "dtype=float16",
                 "--param", "random_state=1", "--param", "progress=false")
    assert result.exit_code == 0, result.output
    assert load(a).get_params() == load(b).get_params()
    assert load(b).dtype == "float16" and load(b).random_state == 1  # progress: a runtime setting, not saved
    # A baseline's own parameters, and the shortcuts it has (--seed is random_state).
    result = run("train", db, "-o", b, "--method", "pq", "--budget", "5KB", "--seed", "3", "--param", "nbits=4",
                 "--overwrite")
    assert result.exit_code == 0, result.output
    assert load(b).get_params()["nbits"] == 4 and load(b).get_params()["random_state"] == 3


@pytest.mark.parametrize(
    "args, code, message",
    [
        (["--method", "btel-c", "--param", "foo=1"], 2, ["btel-c has no parameter 'foo'", "feature_ratio", "sparsity"]),
        (["--method", "pq", "--param", "feature_ratio=0.5"], 2, ["pq has no parameter 'feature_ratio'", "nbits"]),
        (["--method", "bruteforce", "--seed", "1"], 2, ["--seed", "'random_state', which bruteforce does not have",
                                                        "budget, delta, n_jobs"]),
        (["--param", "sparsity"], 2, ["not NAME=VALUE"]),
        (["--param", "pq:nbits=4"], 2, ["'pq', which is not a method of this run"]),
        (["--feature-ratio", "0.2", "--param", "feature_ratio=0.3"], 2, ["both set feature_ratio"]),
        (["--param", "n_features=4", "--param", "n_features=5"], 2, ["twice"]),
        (["--method", "btel-c", "--param", "classifier=tree"], 2,
         ["--param classifier=tree: btel-c's classifier must be 'svm' or 'logistic'"]),
        (["--method", "btel-c", "--param", "feature_ratio=lots"], 2,
         ["--param feature_ratio=lots: btel-c's feature_ratio must be None or a number > 0 and ≤ 1"]),
        (["--method", "pq", "--param", 'budget={"KB": 5}'], 2,
         ['--param budget={"KB": 5}: pq\'s budget must be a byte budget such as']),
        (["--method", "btel-c", "--regions", "many"], 2, ["--regions many: btel-c's n_regions must be"]),
    ],
)
def test_train_param_errors_name_method_parameter_and_choices(args, code, message, small_pair, tmp_path: Path) -> None:
    db, _ = small_pair
    result = CliRunner().invoke(main, ["train", str(db), "-o", str(tmp_path / "m.npz"), *args])
    assert result.exit_code == code, result.output
    assert "Traceback" not in result.output and result.output.strip().count("\n") <= 4
    error = result.output.strip().splitlines()[-1]
    assert error.startswith("Error: ")
    for part in message:
        assert part in error
    assert not (tmp_path / "m.npz").exists()


@pytest.mark.parametrize("method", ["pq", "opq", "itq", "bruteforce", "btel-codes", "btel-c"])
def test_runtime_flags_apply_where_the_method_has_them_and_are_ignored_elsewhere(method: str, small_pair,
                                                                                 tmp_path: Path) -> None:
    from btel import load, make_method

    db, _ = small_pair
    out = tmp_path / "m.npz"
    budget = [] if method == "bruteforce" else ["--budget", "20KB"]
    result = run("train", db, "-o", out, "--method", method, *budget, "--no-progress", "--n-jobs", "1")
    assert result.exit_code == 0, result.output
    assert type(load(out)) is type(make_method(method))  # runtime settings are not saved: check what was passed
    from btel.cli._params import _params_by_method

    given = _params_by_method([method], (), shortcuts={"progress": ("--no-progress", False),
                                                       "n_jobs": ("--n-jobs", 1)})[method]
    valid = make_method(method).get_params()
    assert given == {k: v for k, v in {"progress": False, "n_jobs": 1}.items() if k in valid}


def test_runtime_flags_in_evaluate_for_mixed_methods(small_pair, tmp_path: Path) -> None:
    db, q = small_pair
    result = run("evaluate", "--db", db, "--queries", q, "--methods", "btel-c,pq,itq", "--budget", "8KB",
                 "--no-progress", "--n-jobs", "1", "--out", tmp_path / "run")
    assert result.exit_code == 0, result.output


def test_evaluate_and_demo_params_for_every_method_or_one(small_pair, tmp_path: Path) -> None:
    db, q = small_pair
    out = tmp_path / "run"
    result = run("evaluate", "--db", db, "--queries", q, "--methods", "btel-c,btel-r,pq", "--budget", "8KB",
                 "--param", "progress=false", "--param", "btel-r:progress=false", "--param", "btel-r:n_regions=2",
                 "--param", "pq:nbits=4", "--param", "btel-c:budget=4KB", "--out", out)
    assert "progress" in result.output and result.exit_code == 2  # pq has no progress: --param applies to every method
    result = run("evaluate", "--db", db, "--queries", q, "--methods", "btel-c,btel-r,pq", "--budget", "8KB",
                 "--param", "btel-c:progress=false", "--param", "btel-r:progress=false", "--param", "btel-r:n_regions=2",
                 "--param", "pq:nbits=4", "--param", "btel-c:budget=4KB", "--param", "n_jobs=1", "--out", out)
    assert result.exit_code == 0, result.output
    params = {r["name"]: r["params"] for r in json.loads((out / "metrics.json").read_text())["results"]}
    assert params["btel-r"]["n_regions"] == 2 and params["btel-c"]["n_regions"] == 1
    assert params["pq"]["nbits"] == 4 and params["btel-c"]["budget"] == "4KB" and params["pq"]["budget"] == "8KB"
    assert all(p["n_jobs"] == 1 for p in params.values())
    result = run("evaluate", "--model", tmp_path / "m.npz", "--queries", q, "--param", "nbits=4", "--out", out)
    assert result.exit_code == 2 and "--db" in result.output

    demo_out = tmp_path / "demo"
    result = run("demo", "--places", "200", "--dim", "32", "--methods", "btel-c,pq", "--budget", "10KB",
                 "--param", "btel-c:feature_ratio=0.25", "--out", demo_out)
    assert result.exit_code == 0, result.output
    params = {r["name"]: r["params"] for r in json.loads((demo_out / "metrics.json").read_text())["results"]}
    assert params["btel-c"]["feature_ratio"] == 0.25 and "feature_ratio" not in params["pq"]
    result = run("demo", "--places", "200", "--dim", "32", "--methods", "btel-c,pq", "--param", "pq:depth=3",
                 "--out", tmp_path / "demo2")
    assert result.exit_code == 2 and "pq has no parameter 'depth'" in result.output
    assert not (tmp_path / "demo2").exists()


def test_an_every_method_param_skips_the_reference_row_btel_added_where_it_lacks_it(small_pair, tmp_path: Path) -> None:
    """`--methods lsh --param random_state=3` was refused: "bruteforce has no parameter 'random_state'", for the
    reference row the user never named. Named, bruteforce still refuses it."""
    db, q = small_pair
    out = tmp_path / "run"
    result = run("evaluate", "--db", db, "--queries", q, "--methods", "lsh", "--budget", "4KB", "--param",
                 "random_state=3", "--no-progress", "--out", out)
    assert result.exit_code == 0, result.output
    params = {r["name"]: r["params"] for r in json.loads((out / "metrics.json").read_text())["results"]}
    assert params["lsh"]["random_state"] == 3 and "random_state" not in params["bruteforce"]
    result = run("evaluate", "--db", db, "--queries", q, "--methods", "lsh,bruteforce", "--budget", "4KB", "--param",
                 "random_state=3", "--out", tmp_path / "run2")
    assert result.exit_code == 2 and "bruteforce has no parameter 'random_state'" in result.output


def test_methods_lists_parameters() -> None:
    result = run("methods", "--params")
    assert result.exit_code == 0
    params: dict[str, list[str]] = {}
    for line in result.output.splitlines():
        if line[:1].strip():
            method = line.split()[0]
            params[method] = []
        else:
            params[method].append(line.strip())
    assert any(p.startswith("n_regions=20:") for p in params["btel-r"])
    # Each parameter: default, allowed values (declared constraints), meaning (docstring).
    nbits = next(p for p in params["pq"] if p.startswith("nbits="))
    assert nbits.startswith("nbits=null: None or an integer ≥ 1 and ≤ 8 — Bits per sub-quantiser")
    assert any(p.startswith("progress=true [runtime]: True or False — ") for p in params["btel-c"])
    from btel.methods import METHODS, make_method

    assert set(params) == set(METHODS)
    for name, lines in params.items():
        assert len(lines) == len(make_method(name).get_params())
        assert all(" — " in line for line in lines), name  # every parameter has a meaning


def test_info_shows_what_fitting_chose_and_every_stored_array(small_pair, tmp_path: Path) -> None:
    db, _ = small_pair
    model = tmp_path / "pq.npz"
    assert run("train", db, "-o", model, "--method", "pq", "--budget", "20KB", "--whiten", "16").exit_code == 0
    out = run("info", model).output
    assert "n_subquantizers=null (chosen: " in out and "nbits=null (chosen: " in out
    assert "chosen at fit: dim=11" in out  # 11 × 8 bits of the 16 whitened dims: the most code bits in 20 KB
    assert "pca_dim=null (chosen: 11)" in out  # its state calls it dim: shown as metrics.json records it
    codes = tmp_path / "codes.npz"
    assert run("train", db, "-o", codes, "--method", "btel-codes", "--budget", "8KB").exit_code == 0
    assert "code=auto (chosen: " in run("info", codes).output  # a parameter given as 'auto' too
    assert "stored arrays:" in out and "frontend_whitening" in out and "64 × 16  float32         4,096 B" in out
    from btel import __version__

    assert f"saved by: btel {__version__} on 20" in out  # which btel wrote the file, and when
    old = Path(__file__).parent / "data" / "btel-c-blocks-saved-before-n_blocks.btel"
    assert "saved by: not recorded" in run("info", old).output


def test_train_and_info_say_how_much_of_the_budget_the_model_uses(small_pair, tmp_path: Path) -> None:
    db, _ = small_pair
    capped, spent = tmp_path / "itq.npz", tmp_path / "lsh.npz"
    trained = run("train", db, "-o", capped, "--method", "itq", "--budget", "1MB")
    assert trained.exit_code == 0 and "the largest model its parameters allow" in trained.output
    line = next(line for line in run("info", capped).output.splitlines() if line.strip().startswith("budget "))
    assert "1,000,000 B" in line and "% used: the largest model its parameters allow" in line
    assert run("train", db, "-o", spent, "--method", "lsh", "--budget", "2KB").exit_code == 0
    line = next(line for line in run("info", spent).output.splitlines() if line.strip().startswith("budget "))
    assert line.split()[:3] == ["budget", "2,000", "B"] and line.endswith("% used)")  # no cap reached


def test_messages_name_what_is_missing_in_the_command_lines_words(small_pair, tmp_path: Path) -> None:
    """`localize MODEL q.npy` without -o said "give QUERIES and -o/--output" though QUERIES was given;
    `demo --places 0` named the library's n_places."""
    db, q = small_pair
    model = tmp_path / "m.npz"
    assert run("train", db, "-o", model, "--method", "lsh", "--budget", "4KB").exit_code == 0
    result = run("localize", model, q)
    assert result.exit_code == 2 and "give -o/--output FILE (or use --stream)" in result.output
    assert "QUERIES" not in result.output.splitlines()[-1]
    result = run("demo", "--places", "1", "--out", tmp_path / "demo")
    assert result.exit_code == 2 and "'--places'" in result.output and "n_places" not in result.output


def test_a_malformed_memory_limit_is_named_as_itself_by_every_command(small_pair, tmp_path: Path) -> None:
    """BTEL_MEMORY_LIMIT=abc: `btel info` blamed the model file ("inconsistent with a … model"), `btel train`
    went on silently."""
    db, _ = small_pair
    model = tmp_path / "m.npz"
    assert run("train", db, "-o", model, "--method", "lsh", "--budget", "4KB").exit_code == 0
    for args in (["info", model], ["train", db, "-o", tmp_path / "m2.npz", "--method", "lsh", "--budget", "4KB"]):
        result = CliRunner().invoke(main, [str(a) for a in args], env={"BTEL_MEMORY_LIMIT": "abc"})
        assert result.exit_code == 2 and "BTEL_MEMORY_LIMIT='abc' is not a size" in result.output
        assert "inconsistent" not in result.output
    assert not (tmp_path / "m2.npz").exists()
