"""The command line's rules, each checked over every command: exit statuses and words.

2: a usage or input error (nothing ran); 1: a failure while running; 130: Ctrl-C. Every error is
one line in the command line's words: no traceback, no Python call syntax (``overwrite=True``), no
Python value (``{'KB': 5}``).
"""

from __future__ import annotations

import errno
import re
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

import btel
from btel.cli import EXIT_FAILURE, EXIT_INTERRUPTED, EXIT_USAGE, main
from btel.cli._errors import exit_status
from btel.exceptions import (BudgetExceededError, DataNotFoundError, InvalidDescriptorsError, ModelFileError,
                             OutputExistsError)

#: Every command of `btel` (the rules below are parametrised over all of them).
COMMANDS = ["train", "localize", "evaluate", "extract", "info", "methods", "experiment", "report", "demo", "show"]

_PYTHON_WORDS = re.compile(r"\b\w+=(True|False|None)\b|\{'|\['|Traceback|\bkey='|\bfit_on=")


@pytest.fixture()
def files(tmp_path: Path) -> dict[str, Path]:
    rng = np.random.default_rng(0)
    X = rng.standard_normal((60, 16)).astype(np.float32)
    np.save(tmp_path / "db.npy", X)
    np.save(tmp_path / "q.npy", X + 0.01)
    np.savetxt(tmp_path / "db.txt", X)
    (tmp_path / "junk.npz").write_bytes(b"not a model at all")
    (tmp_path / "taken").mkdir()
    (tmp_path / "taken" / "metrics.json").write_text("{}")
    (tmp_path / "images").mkdir()
    (tmp_path / "empty_runs").mkdir()
    return {"dir": tmp_path, "db": tmp_path / "db.npy", "q": tmp_path / "q.npy"}


def _args(command: str, f: dict[str, Path]) -> dict[str, list[str]]:
    """Per rule, a command line of ``command`` that meets it: "usage" a usage or input error, "run"
    one that gets to running (where the tests make the library fail or be interrupted)."""
    d = f["dir"]
    model = d / "m.npz"
    table = {
        "train": {"usage": ["train", str(d / "db.txt"), "-o", str(model)],
                  "run": ["train", str(f["db"]), "-o", str(model), "--method", "bruteforce"]},
        "localize": {"usage": ["localize", str(d / "junk.npz"), str(f["q"]), "-o", str(d / "p.csv")],
                     "run": ["localize", str(d / "junk.npz"), str(f["q"]), "-o", str(d / "p.csv")]},
        "evaluate": {"usage": ["evaluate", "--db", str(f["db"]), "--queries", str(f["q"]), "--methods", "bruteforce",
                               "--out", str(d / "taken")],
                     "run": ["evaluate", "--db", str(f["db"]), "--queries", str(f["q"]), "--methods", "bruteforce",
                             "--out", str(d / "run"), "--no-progress"]},
        "extract": {"usage": ["extract", str(d / "no-such-folder"), "-o", str(d / "x.npy")],
                    "run": ["extract", str(d / "images"), "-o", str(d / "x.npy")]},
        "info": {"usage": ["info", str(d / "junk.npz")], "run": ["info", str(d / "junk.npz")]},
        "methods": {"usage": ["methods", "--no-such-flag"], "run": ["methods"]},
        "experiment": {"usage": ["experiment", "no-such-experiment", "--out", str(d / "exp")],
                       "run": ["experiment", "accuracy", "--quick", "--out", str(d / "exp")]},
        "report": {"usage": ["report", "--runs", str(d / "empty_runs"), "--docs", str(d / "docs")],
                   "run": ["report", "--runs", str(d / "empty_runs"), "--docs", str(d / "docs")]},
        "demo": {"usage": ["demo", "--places", "50", "--dim", "8", "--methods", "pq", "--param", 'budget={"KB": 5}',
                           "--out", str(d / "demo")],
                 "run": ["demo", "--places", "50", "--dim", "8", "--methods", "pq", "--out", str(d / "demo"),
                         "--no-progress"]},
        "show": {"usage": ["show", str(d / "empty_runs")], "run": ["show", str(d / "taken")]},
    }
    return table[command]


def _raise_in(command: str, monkeypatch: pytest.MonkeyPatch, error: BaseException) -> None:
    """Make the library call ``command`` runs first raise ``error``."""
    def fail(*args, **kwargs):
        raise error

    import btel.cli._gallery
    import btel.cli.evaluate
    import btel.cli.localize
    import btel.cli.train
    import btel.datasets
    import btel.evaluation.runfile
    import btel.descriptors.extract
    import btel.experiments
    import btel.experiments.report
    import btel.methods.registry

    target = {"train": (btel.cli.train, "_load_map"), "localize": (btel.cli.localize, "_load_matrix"),
              "evaluate": (btel.cli.evaluate, "_load_matrix"), "extract": (btel.descriptors.extract, "extract_cached"),
              "info": (btel, "load"), "methods": (btel.methods.registry, "make_method"),
              "experiment": (btel.experiments, "run_experiment"), "report": (btel.experiments.report, "write_report"),
              "demo": (btel.datasets, "synthetic_route"), "show": (btel.evaluation.runfile, "describe_run")}[command]
    if command == "localize":
        monkeypatch.setattr(btel, "load", lambda path: None)
    monkeypatch.setattr(*target, fail)


def _invoke(args: list[str]):
    return CliRunner().invoke(main, args)


def _check_words(result) -> str:
    error = result.output.strip().splitlines()[-1] if result.output.strip() else ""
    assert error.startswith(("Error: ", "Interrupted.")), result.output
    assert not _PYTHON_WORDS.search(result.output), result.output
    return error


@pytest.mark.parametrize("command", COMMANDS)
def test_a_usage_or_input_error_exits_2_in_the_command_lines_words(command: str, files) -> None:
    result = _invoke(_args(command, files)["usage"])
    assert result.exit_code == EXIT_USAGE, result.output
    error = _check_words(result)
    if command == "train":  # a text file is not called a pickle
        assert "not a .npy file" in error and "pickle" not in error
    if command == "evaluate":  # an existing run folder, in the command line's words
        assert "--overwrite" in error
    if command == "demo":  # a budget that is not one, as it was typed
        assert '--param budget={"KB": 5}' in error


@pytest.mark.parametrize("command", COMMANDS)
def test_a_failure_while_running_exits_1(command: str, files, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(files["dir"])
    _raise_in(command, monkeypatch, OSError(errno.ENOSPC, "No space left on device"))
    result = _invoke(_args(command, files)["run"])
    assert result.exit_code == EXIT_FAILURE, result.output
    assert "No space left on device" in _check_words(result)


@pytest.mark.parametrize("command", COMMANDS)
def test_ctrl_c_exits_130(command: str, files, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(files["dir"])
    _raise_in(command, monkeypatch, KeyboardInterrupt())
    result = _invoke(_args(command, files)["run"])
    assert result.exit_code == EXIT_INTERRUPTED, result.output
    assert "Traceback" not in result.output


@pytest.mark.parametrize("error, status", [
    (InvalidDescriptorsError("x"), 2), (ModelFileError("x"), 2), (DataNotFoundError("x"), 2),
    (OutputExistsError("x"), 2), (FileNotFoundError("x"), 2), (ValueError("x"), 2), (KeyError("x"), 2),
    (BudgetExceededError("x"), 1), (OSError(errno.ENOSPC, "full"), 1), (OSError(errno.EIO, "io"), 1),
    (MemoryError(), 1),
])
def test_each_kind_of_error_has_its_status(error: BaseException, status: int) -> None:
    assert exit_status(error) == status


def test_a_run_with_a_row_that_does_not_fit_exits_1_with_the_run_written(files) -> None:
    out = files["dir"] / "tight"
    result = _invoke(["demo", "--places", "200", "--dim", "16", "--methods", "pq", "--budget", "100B",
                      "--out", str(out), "--no-progress"])
    assert result.exit_code == EXIT_FAILURE, result.output
    assert (out / "metrics.json").is_file() and "pq (does not fit)" in result.output
