"""btel report never loses a page unasked (btel.experiments.reportfiles.check_nothing_lost)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from click.testing import CliRunner

from btel.cli import main
from btel.exceptions import OutputExistsError
from btel.experiments.report import write_report


def _run(runs: Path, name: str, quick: bool) -> None:
    (runs / name).mkdir(parents=True, exist_ok=True)
    (runs / name / "results.json").write_text(json.dumps({"rows": [], "run": {"quick": quick}}))


@pytest.fixture()
def published(tmp_path: Path) -> Path:
    """A docs folder whose page was reported from full runs of accuracy and vs-n."""
    _run(tmp_path / "full", "accuracy", quick=False)
    _run(tmp_path / "full", "vs-n", quick=False)
    write_report(tmp_path / "full", tmp_path / "docs")
    return tmp_path / "docs"


def test_a_quick_run_does_not_replace_a_full_page_unasked(published: Path, tmp_path: Path) -> None:
    before = {p.name: p.read_bytes() for p in (published / "results.md", published / "results.json")}
    _run(tmp_path / "quick", "accuracy", quick=True)
    result = CliRunner().invoke(main, ["report", "--runs", str(tmp_path / "quick"), "--docs", str(published)])
    assert result.exit_code != 0
    message = " ".join(result.output.split())
    assert "drop the sections of vs-n" in message and "replace the full run of accuracy with quick-mode" in message
    assert "--overwrite" in message and "--docs" in message
    assert {p.name: p.read_bytes() for p in (published / "results.md", published / "results.json")} == before
    # Asked for, it is replaced; another --docs folder is written without a word.
    assert CliRunner().invoke(main, ["report", "--runs", str(tmp_path / "quick"), "--docs", str(tmp_path / "look")]
                              ).exit_code == 0
    result = CliRunner().invoke(main, ["report", "--runs", str(tmp_path / "quick"), "--docs", str(published),
                                       "--overwrite"])
    assert result.exit_code == 0, result.output
    assert list(json.loads((published / "results.json").read_text())) == ["accuracy"]


def test_full_runs_of_the_same_experiments_replace_the_page(published: Path, tmp_path: Path) -> None:
    _run(tmp_path / "again", "accuracy", quick=False)
    _run(tmp_path / "again", "vs-n", quick=False)
    _run(tmp_path / "again", "regions", quick=True)  # a section the page did not have: nothing is lost
    write_report(tmp_path / "again", published)
    assert set(json.loads((published / "results.json").read_text())) == {"accuracy", "vs-n", "regions"}
    _run(tmp_path / "again", "regions", quick=False)
    write_report(tmp_path / "again", published)  # a quick section replaced by a full one
    with pytest.raises(OutputExistsError, match="drop the sections of regions"):
        write_report(tmp_path / "full", published)


def test_a_reported_page_without_its_record_is_kept(published: Path, tmp_path: Path) -> None:
    """A docs folder holding the report's results.md but not its results.json was replaced by a quick run's page;
    a results.md of benchmark marker blocks only is still written into."""
    (published / "results.json").unlink()
    before = (published / "results.md").read_bytes()
    _run(tmp_path / "quick", "accuracy", quick=True)
    with pytest.raises(OutputExistsError, match="results.md without the results.json"):
        write_report(tmp_path / "quick", published)
    assert (published / "results.md").read_bytes() == before
    (tmp_path / "fresh").mkdir()
    (tmp_path / "fresh" / "results.md").write_text("<!-- scale:start -->\nSCALE\n<!-- scale:end -->\n")
    assert "SCALE" in write_report(tmp_path / "quick", tmp_path / "fresh").read_text()
