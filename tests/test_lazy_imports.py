"""``import btel`` and ``btel --help`` do not import scikit-learn (their start-up cost; timings: benchmarks/bench_import.py)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import btel

SRC = str(Path(btel.__file__).resolve().parents[1])


def modules_after(code: str) -> set[str]:
    env = {**os.environ, "PYTHONPATH": SRC}
    out = subprocess.run([sys.executable, "-c", code + "\nimport sys; print('\\n'.join(sys.modules))"], env=env,
                         check=True, capture_output=True, text=True).stdout
    return set(out.split())


def test_import_btel_does_not_import_sklearn() -> None:
    loaded = modules_after("import btel")
    assert "btel" in loaded
    assert not {m for m in loaded if m.split(".")[0] in ("sklearn", "scipy")}


def test_btel_help_does_not_import_sklearn() -> None:
    code = ("import sys; sys.argv = ['btel', '--help']\nfrom btel.cli import main\n"
            "try:\n    main()\nexcept SystemExit:\n    pass")
    loaded = modules_after(code)
    assert "btel.cli" in loaded and "click" in loaded
    assert not {m for m in loaded if m.split(".")[0] in ("sklearn", "scipy")}


def test_public_names_are_unchanged_and_listed() -> None:
    names = {"BTELocalizer", "CodeLocalizer", "PlaceLocalizer", "SequenceFilter", "filter_sequence", "load",
             "make_method", "parse_budget", "__version__"}
    assert set(btel.__all__) == names
    assert names <= set(dir(btel))
    from btel.methods.btel.localizer import BTELocalizer

    assert btel.BTELocalizer is BTELocalizer
    from btel import load, make_method  # noqa: F401  (from-imports resolve through __getattr__)


def test_an_unknown_name_is_an_attribute_error() -> None:
    try:
        btel.NoSuchThing  # noqa: B018
    except AttributeError as exc:
        assert "NoSuchThing" in str(exc)
    else:  # pragma: no cover
        raise AssertionError("btel.NoSuchThing did not raise AttributeError")


def test_python_m_btel_cli_runs() -> None:
    env = {**os.environ, "PYTHONPATH": SRC}
    out = subprocess.run([sys.executable, "-m", "btel.cli", "--version"], env=env, capture_output=True, text=True)
    assert out.returncode == 0 and "btel" in out.stdout


def test_btel_help_does_not_import_numpy() -> None:
    code = ("import sys; sys.argv = ['btel', '--help']\nfrom btel.cli import main\n"
            "try:\n    main()\nexcept SystemExit:\n    pass")
    assert "numpy" not in modules_after(code)
