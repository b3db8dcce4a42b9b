"""--budget on the command line: every spelling a user might type gets bytes or an error naming the fix."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from btel.cli import main
from btel.cli._errors import unitless_budget_hint


@pytest.fixture()
def db(tmp_path: Path) -> Path:
    X = np.random.default_rng(0).standard_normal((300, 64)).astype(np.float32)
    np.save(tmp_path / "db.npy", X)
    return tmp_path / "db.npy"


def _train(db: Path, budget: str) -> "click.testing.Result":  # noqa: F821
    out = db.parent / "m.npz"
    return CliRunner().invoke(main, ["train", str(db), "-o", str(out), "--budget", budget, "--no-progress"])


@pytest.mark.parametrize("budget, words", [
    ("1e2", ["did you mean 1e2KB?"]),             # a unitless number under 1000, however written
    ("0", ["must be a positive number of bytes"]),  # no hint that would be refused in turn
    ("-5KB", ["must be a positive number of bytes"]),
    ("10Kb", ["reads as bits", "'10KB' for bytes"]),
    ("64KB,128KB", ["takes one budget", "btel evaluate --budget 64KB,128KB"]),
])
def test_train_names_what_is_wrong_with_a_budget(db: Path, budget: str, words: list[str]) -> None:
    result = _train(db, budget)
    assert result.exit_code == 2, result.output
    assert "Traceback" not in result.output
    for w in words:
        assert w in result.output
    assert not (db.parent / "m.npz").exists()


@pytest.mark.parametrize("budget", ["8KB", "8kb", "8000", "8 KB"])
def test_train_takes_the_spellings_of_bytes(db: Path, budget: str) -> None:
    assert _train(db, budget).exit_code == 0


@pytest.mark.parametrize("text, hint", [("32", "32KB"), ("0.5", "0.5KB"), ("1e2", "1e2KB"), ("0", None),
                                        ("1000", None), ("2e3", None), ("32KB", None)])
def test_unitless_budget_hint(text: str, hint: str | None) -> None:
    assert unitless_budget_hint(text) == hint
