"""Hostile inputs to ``btel report`` and to a saved auto model: each ends with one clear error, no traceback.

``btel report`` reads and copies regular files only, each of bounded size, refuses an output in ``docs/``
that is not a regular file, and checks the fields of ``results.json`` it reads
(``btel.experiments.report``). An auto model whose saved ``state.choice`` is damaged is refused when
it is loaded (``btel.methods.auto.localizer.check_saved_choice``).
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

import btel
from btel.cli import main
from btel.core.modelfile import load_arrays, save_arrays
from btel.exceptions import InvalidParameterError, ModelFileError
from btel.experiments import report as report_module
from btel.experiments import reportfiles
from btel.experiments.report import write_report
from btel.methods import make_method

_EMPTY = {"rows": [], "run": {}}


@pytest.fixture()
def runs(tmp_path: Path) -> tuple[Path, Path, Path]:
    """(runs dir, docs dir, the accuracy run folder) holding an empty but valid results.json."""
    folder = tmp_path / "runs" / "accuracy"
    folder.mkdir(parents=True)
    (folder / "results.json").write_text(json.dumps(_EMPTY))
    (tmp_path / "docs").mkdir()
    return tmp_path / "runs", tmp_path / "docs", folder


def _special(kind: str, where: Path) -> None:
    """Make ``where`` a symlink to a device or folder, or a FIFO."""
    if kind == "fifo":
        os.mkfifo(where)
    else:
        os.symlink({"devzero": "/dev/zero", "dir": str(where.parent)}[kind], where)


def _report(runs_dir: Path, docs: Path) -> "click.testing.Result":  # noqa: F821
    return CliRunner().invoke(main, ["report", "--runs", str(runs_dir), "--docs", str(docs)], catch_exceptions=False)


@pytest.mark.skipif(not os.path.exists("/dev/zero") or not hasattr(os, "mkfifo"), reason="POSIX special files")
@pytest.mark.parametrize("kind", ["devzero", "fifo", "dir"])
@pytest.mark.parametrize("where", ["figure", "results.md", "results.json", "written figure"])
def test_report_refuses_special_files(runs, kind: str, where: str) -> None:
    runs_dir, docs, folder = runs
    path = {"figure": folder / "fig.png", "results.md": docs / "results.md", "results.json": docs / "results.json",
            "written figure": docs / "figures" / "accuracy-fig.png"}[where]
    if where == "written figure":
        (folder / "fig.png").write_bytes(b"\x89PNG")
        path.parent.mkdir()
    _special(kind, path)
    with pytest.raises(InvalidParameterError, match="not a regular file") as info:
        write_report(runs_dir, docs)
    assert str(path) in str(info.value)
    result = _report(runs_dir, docs)
    assert result.exit_code == 2 and result.output.startswith("Error:") and len(result.output.splitlines()) == 1


def test_report_follows_a_symlink_to_a_regular_figure(runs) -> None:
    runs_dir, docs, folder = runs
    (folder.parent / "real.png").write_bytes(b"\x89PNG figure")
    os.symlink(folder.parent / "real.png", folder / "fig.png")
    write_report(runs_dir, docs)
    assert (docs / "figures" / "accuracy-fig.png").read_bytes() == b"\x89PNG figure"
    assert not (docs / "figures" / "accuracy-fig.png").is_symlink()


@pytest.mark.parametrize("what", ["figure", "results.json", "results.md"])
def test_report_reads_at_most_its_size_limits(runs, monkeypatch, what: str) -> None:
    runs_dir, docs, folder = runs
    monkeypatch.setattr(report_module, "MAX_FIGURE_BYTES", 64)
    monkeypatch.setattr(reportfiles, "MAX_TEXT_BYTES", 64)
    if what == "figure":
        (folder / "fig.png").write_bytes(b"x" * 65)
    elif what == "results.json":
        (folder / "results.json").write_text(json.dumps({**_EMPTY, "pad": "x" * 64}))
    else:
        (docs / "results.md").write_text("x" * 65)
    with pytest.raises(InvalidParameterError, match="more than 64 bytes"):
        write_report(runs_dir, docs)


@pytest.mark.parametrize("payload, field", [
    ([1], "a JSON list"),
    ({"rows": [], "run": []}, "'run' must be an object"),
    ({"rows": {}, "run": {}}, "'rows' must be a list"),
    ({"rows": [1], "run": {}}, "'rows' must be a list of objects"),
    ({"rows": [{"method": 1}], "run": {"seconds": "x"}}, "'run.seconds'"),
    ({"rows": [], "run": {"versions": "x"}}, "'run.versions'"),
    ({"rows": [], "run": {"quick": "yes"}}, "'run.quick'"),
    ({"rows": [{"method": "a", "n_places": 3, "nbytes": "5KB"}], "run": {}}, "'rows\\[0\\].nbytes'"),
    ({"rows": [{"method": "a", "n_places": 3, "recall@10": "x"}], "run": {}}, "'rows\\[0\\].recall@10'"),
    ({"rows": [{"method": "a", "n_places": 3, "status": 1}], "run": {}}, "'rows\\[0\\].status'"),
    ({"rows": [{"method": "a"}], "run": {}}, "KeyError: 'n_places'"),
    ({"rows": [{"method": "a", "n_places": 3, "status": "ok"}], "run": {}}, "KeyError: 'recall@0'"),
    ("{not json", "not JSON"),
])
def test_report_names_the_damaged_field_of_results_json(runs, payload: object, field: str) -> None:
    runs_dir, docs, folder = runs
    (folder / "results.json").write_text(payload if isinstance(payload, str) else json.dumps(payload))
    with pytest.raises(InvalidParameterError, match=field) as info:
        write_report(runs_dir, docs)
    assert str(folder / "results.json") in str(info.value) and "btel experiment accuracy" in str(info.value)
    result = _report(runs_dir, docs)
    assert result.exit_code == 2 and result.output.startswith("Error:") and len(result.output.splitlines()) == 1


# -- a saved auto model whose state.choice is damaged ------------------------------------------------------------

@pytest.fixture(scope="module")
def auto_files(tmp_path_factory) -> tuple[Path, Path]:
    """(plain auto model, calibrated auto model) saved on a small random map."""
    rng = np.random.default_rng(0)
    X = rng.standard_normal((200, 64)).astype(np.float32)
    folder = tmp_path_factory.mktemp("auto")
    plain = make_method("auto", budget="5KB").fit(X).save(folder / "m.npz")
    calibrated = make_method("auto", budget="5KB").fit(X, calibration=(X[::2] + 0.1, np.arange(200)[::2]))
    return Path(plain), Path(calibrated.save(folder / "mc.npz"))


@pytest.mark.parametrize("calibrated, field, value", [
    (False, ("reason",), 5), (False, ("refused",), -1), (False, ("refused",), [1, "a"]), (False, ("params",), "x"),
    (True, ("calibration", "alpha"), None), (True, ("calibration", "alpha"), "x"),
    (True, ("calibration", "reference_difference"), None), (True, ("calibration", "reference_difference"), []),
    (True, ("calibration", "reference_difference"), {}), (True, ("calibration", "table"), "x"),
    (True, ("calibration",), 3),
])
def test_a_damaged_auto_choice_is_refused_on_load(auto_files, tmp_path, calibrated: bool, field: tuple,
                                                  value: object) -> None:
    arrays, header = load_arrays(auto_files[calibrated])
    assert btel.load(auto_files[calibrated]).summary()  # the intact file loads and describes itself
    header = {k: v for k, v in header.items() if not k.startswith("format")}
    node = header["state"]["choice"]
    for key in field[:-1]:
        node = node[key]
    node[field[-1]] = value
    bad = tmp_path / "bad.npz"
    save_arrays(bad, arrays, header)
    with pytest.raises(ModelFileError, match=f"state.choice.{'.'.join(field)} must be"):
        btel.load(bad)
    result = CliRunner().invoke(main, ["info", str(bad)], catch_exceptions=False)
    assert result.exit_code == 2 and result.output.startswith("Error:") and "Traceback" not in result.output


def test_report_keeps_a_results_file_it_did_not_write_unless_overwrite(tmp_path) -> None:
    """A user's own docs/results.md was replaced without a word."""
    from btel.exceptions import OutputExistsError
    from btel.experiments.report import write_report

    runs, docs = tmp_path / "runs", tmp_path / "docs"
    (runs / "accuracy").mkdir(parents=True)
    (runs / "accuracy" / "results.json").write_text('{"rows": [], "run": {}}')
    docs.mkdir()
    (docs / "results.md").write_text("my notes\n")
    with pytest.raises(OutputExistsError, match="not written by btel report"):
        write_report(runs, docs)
    assert (docs / "results.md").read_text() == "my notes\n"
    assert sorted(p.name for p in docs.iterdir()) == ["results.md"]  # refused before anything was made
    write_report(runs, docs, overwrite=True)
    write_report(runs, docs)  # its own file now: replaced without --overwrite
    assert "Generated by `btel report`" in (docs / "results.md").read_text()
