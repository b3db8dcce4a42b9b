"""A run folder edited, damaged or made hostile: ``btel evaluate --resume RUN`` and ``btel show RUN`` refuse it with
one line naming the file and the fix (exit 2), never a traceback, a failed row or a silent acceptance
(``btel.cli.evaluate``, ``btel.cli._gallery``, ``btel.evaluation.runfile``)."""

from __future__ import annotations

import json
import shutil
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from click.testing import CliRunner, Result

from btel.cli import main
from btel.datasets import synthetic_route


def invoke(*args: object) -> Result:
    return CliRunner().invoke(main, [str(a) for a in args])


def _refused(result: Result, *phrases: str) -> str:
    """The one-line message of a run refused with exit 2 (no traceback), checked to hold ``phrases``."""
    assert result.exit_code == 2 and isinstance(result.exception, SystemExit), (result.exception, result.output)
    text = " ".join(result.output.split())
    assert "Traceback" not in text and all(p in text for p in phrases), text
    return text


@pytest.fixture(scope="module")
def finished_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A finished run of pq at 4KB with the brute-force reference rows."""
    root = tmp_path_factory.mktemp("resume")
    route = synthetic_route(n_places=60, dim=16, seed=2)
    np.save(root / "db.npy", route.map)
    np.save(root / "q.npy", route.queries)
    result = CliRunner().invoke(main, ["evaluate", "--db", str(root / "db.npy"), "--queries", str(root / "q.npy"),
                                       "--methods", "pq", "--budget", "4KB", "--no-progress", "--out",
                                       str(root / "run")])
    assert result.exit_code == 0, result.output
    return root / "run"


def _unfinished(finished_run: Path, tmp_path: Path, edit: Any = None, *, references: bool = True) -> Path:
    """A copy of the finished run marked unfinished, its metrics passed through ``edit``; without its
    reference rows if not ``references`` (so a resume would run them again)."""
    run = tmp_path / "run"
    shutil.copytree(finished_run, run)
    payload = json.loads((run / "metrics.json").read_text())
    payload["run"]["complete"] = False
    if not references:
        payload["results"] = [r for r in payload["results"] if not r["name"].startswith("bruteforce")]
    if edit is not None:
        edit(payload)
    (run / "metrics.json").write_text(json.dumps(payload))
    return run


def _set_option(flag: str, value: Any) -> Any:
    def edit(payload: dict[str, Any]) -> None:
        payload["run"]["extra"]["options"][flag] = value
    return edit


@pytest.mark.parametrize("flag, value", [
    ("--budget", 5), ("--budget", ["5"]), ("--methods", 5), ("--methods", []), ("--param", 3),
    ("--param", [{"a": 1}]), ("--db", 7), ("--ground-truth", {"a": 1}), ("--k", "abc"), ("--k", [True]),
    ("--query-order", "sideways"), ("--no-reference", 0), ("--delta", 2.5), ("--positive-dist-threshold", "25"),
    ("--calibrate-tolerance", -3),
])
def test_resume_refuses_a_recorded_option_its_flag_would_refuse(finished_run: Path, tmp_path: Path, flag: str,
                                                               value: Any) -> None:
    """Each was a TypeError/AttributeError traceback, or (--query-order) accepted silently."""
    run = _unfinished(finished_run, tmp_path, _set_option(flag, value))
    _refused(invoke("evaluate", "--resume", run, "--no-progress"), f"{run / 'metrics.json'}: option {flag} holds",
             "which btel evaluate never writes", "the file was edited or damaged",
             "Run the evaluation again without --resume")


@pytest.mark.parametrize("flag, value", [("--k", [-1, 0]), ("--timing-threads", "x"), ("--timing-threads", -1)])
def test_resume_refuses_a_recorded_value_that_failed_every_row_to_run(finished_run: Path, tmp_path: Path, flag: str,
                                                                    value: Any) -> None:
    """These made every row still to run fail (exit 1, "rows did not run"), as if the command line were right."""
    run = _unfinished(finished_run, tmp_path, _set_option(flag, value), references=False)
    text = _refused(invoke("evaluate", "--resume", run, "--no-progress"), f"option {flag} holds",
                    "Run the evaluation again without --resume")
    assert "did not run" not in text


@pytest.mark.parametrize("field", ["options", "extra"])
def test_resume_refuses_recorded_options_that_are_no_object(finished_run: Path, tmp_path: Path, field: str) -> None:
    """A list there read as "no options recorded": the misleading "give --db …" or "give --methods again"."""
    def edit(payload: dict[str, Any]) -> None:
        if field == "options":
            payload["run"]["extra"]["options"] = []
        else:
            payload["run"]["extra"] = []
    run = _unfinished(finished_run, tmp_path, edit)
    text = _refused(invoke("evaluate", "--resume", run, "--no-progress"), "metrics.json: run.extra",
                    "the file was edited or damaged", "without --resume")
    assert "give --db" not in text and "give --methods" not in text


def test_resume_still_goes_on_with_recorded_options_as_written(finished_run: Path, tmp_path: Path) -> None:
    run = _unfinished(finished_run, tmp_path, references=False)
    result = invoke("evaluate", "--resume", run, "--no-progress")
    assert result.exit_code == 0, result.output
    assert "1 of 3 rows done (pq)" in result.output


def _deep(path: Path) -> None:
    path.write_text("[" * 100_000 + "]" * 100_000)


def test_resume_names_the_file_and_the_fix_for_json_nested_too_deep(finished_run: Path, tmp_path: Path) -> None:
    """Was "Error: RecursionError: maximum recursion depth exceeded …", naming no file and no fix."""
    run = _unfinished(finished_run, tmp_path)
    _deep(run / "metrics.json")
    text = _refused(invoke("evaluate", "--resume", run), str(run / "metrics.json"), "nested deeper",
                    "without --resume")
    assert "RecursionError" not in text


def test_resume_refuses_a_metrics_file_larger_than_any_run_writes(finished_run: Path, tmp_path: Path) -> None:
    from btel.evaluation.runfile import MAX_RUN_JSON_BYTES

    run = _unfinished(finished_run, tmp_path)
    with open(run / "metrics.json", "r+b") as fh:  # sparse: cheap to make, read only up to the cap
        fh.truncate(MAX_RUN_JSON_BYTES + 10)
    _refused(invoke("evaluate", "--resume", run), str(run / "metrics.json"), "more than 64 MiB", "without --resume")


def test_overwrite_of_a_folder_with_deeply_nested_metrics_is_refused_as_no_run(finished_run: Path,
                                                                               tmp_path: Path) -> None:
    """``--overwrite`` reads the old metrics.json to learn which files are a run's: a RecursionError before."""
    run = _unfinished(finished_run, tmp_path)
    _deep(run / "metrics.json")
    root = finished_run.parent
    _refused(invoke("evaluate", "--db", root / "db.npy", "--queries", root / "q.npy", "--methods", "pq",
                    "--budget", "4KB", "--no-progress", "--out", run, "--overwrite"), "but no btel run",
             "Choose another --out folder")


# -- btel show -------------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def image_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A finished run on descriptors `btel extract` wrote from 6 textured images (map = queries), galleries
    removed so that `btel show` draws them."""
    import cv2

    root = tmp_path_factory.mktemp("show")
    folder = root / "images"
    folder.mkdir()
    for i in range(6):
        cv2.imwrite(str(folder / f"{i}.png"), np.random.default_rng(i).integers(0, 256, (32, 64), dtype=np.uint8))
    runner = CliRunner()
    result = runner.invoke(main, ["extract", str(folder), "-o", str(root / "db.npy"), "--descriptor", "patchnorm",
                                  "--size", "56x32", "--no-progress"])
    assert result.exit_code == 0, result.output
    result = runner.invoke(main, ["evaluate", "--db", str(root / "db.npy"), "--queries", str(root / "db.npy"),
                                  "--methods", "bruteforce", "--no-reference", "--no-progress", "--out",
                                  str(root / "run")])
    assert result.exit_code == 0, result.output
    for png in (root / "run").glob("gallery_*.png"):
        png.unlink()
    return root / "run"


def _show_copy(image_run: Path, tmp_path: Path) -> Path:
    run = tmp_path / "run"
    shutil.copytree(image_run, run)
    return run


def test_show_draws_the_gallery_of_an_intact_run(image_run: Path, tmp_path: Path) -> None:
    run = _show_copy(image_run, tmp_path)
    result = invoke("show", run)
    assert result.exit_code == 0, result.output
    assert (run / "gallery_bruteforce.png").is_file()


@pytest.mark.parametrize("edit, phrase", [
    (lambda cells: ["5"], "line 4: the row has fewer cells"),  # a short row: int(None), a TypeError traceback before
    (lambda cells: [*cells, "x"], "line 4: the row has more cells"),
    (lambda cells: [cells[0], "abc", *cells[2:]], "line 4: prediction is 'abc'"),
    (lambda cells: [cells[0], "99", *cells[2:]], "line 4: prediction is '99'"),  # outside the 6 map images
])
def test_show_names_the_predictions_file_and_row_of_a_damaged_row(image_run: Path, tmp_path: Path, edit: Any,
                                                                  phrase: str) -> None:
    run = _show_copy(image_run, tmp_path)
    predictions = run / "predictions_bruteforce.csv"
    lines = predictions.read_text().splitlines()
    lines[3] = ",".join(edit(lines[3].split(",")))
    predictions.write_text("\n".join(lines) + "\n")
    _refused(invoke("show", run), f"{predictions}, {phrase}", "run `btel evaluate` again")
    assert not (run / "gallery_bruteforce.png").exists()


def test_show_refuses_a_row_name_that_is_no_string(image_run: Path, tmp_path: Path) -> None:
    """``results[0].name = 5`` was a TypeError traceback in safe_file_name."""
    run = _show_copy(image_run, tmp_path)
    payload = json.loads((run / "metrics.json").read_text())
    payload["results"][0]["name"] = 5
    (run / "metrics.json").write_text(json.dumps(payload))
    _refused(invoke("show", run), f"{run / 'metrics.json'}: results[0]", "field 'name' must be a string",
             "run `btel evaluate` again")


def test_show_names_the_file_and_the_fix_for_json_nested_too_deep(image_run: Path, tmp_path: Path) -> None:
    run = _show_copy(image_run, tmp_path)
    _deep(run / "metrics.json")
    text = _refused(invoke("show", run), str(run / "metrics.json"), "nested deeper", "run `btel evaluate` again")
    assert "RecursionError" not in text


def test_show_refuses_a_metrics_file_larger_than_any_run_writes(image_run: Path, tmp_path: Path) -> None:
    from btel.evaluation.runfile import MAX_RUN_JSON_BYTES

    run = _show_copy(image_run, tmp_path)
    with open(run / "metrics.json", "r+b") as fh:
        fh.truncate(MAX_RUN_JSON_BYTES + 10)
    _refused(invoke("show", run), str(run / "metrics.json"), "more than 64 MiB")


@pytest.mark.parametrize("libraries", [-1, 1.5, True, "openblas", {"a": 1}])
def test_btel_show_reads_a_run_whose_thread_libraries_are_no_list(finished_run: Path, tmp_path: Path,
                                                                  libraries: Any) -> None:
    """`run.threads.libraries` edited to a number raised TypeError with a traceback (exit 1)."""
    run = tmp_path / "run"
    shutil.copytree(finished_run, run)
    data = json.loads((run / "metrics.json").read_text())
    data["run"]["threads"]["libraries"] = libraries
    (run / "metrics.json").write_text(json.dumps(data))
    result = invoke("show", run)
    assert result.exit_code == 0, result.output
    assert "Traceback" not in result.output and "machine:" in result.output
