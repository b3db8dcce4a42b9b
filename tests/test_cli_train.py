"""``btel train``: what a newcomer gets wrong is refused with the step that fixes it."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from btel.cli import main


def _invoke(*args) -> "click.testing.Result":  # noqa: F821
    return CliRunner().invoke(main, [str(a) for a in args])


@pytest.fixture()
def db(tmp_path: Path) -> Path:
    np.save(tmp_path / "db.npy", np.random.default_rng(0).standard_normal((40, 8)).astype(np.float32))
    return tmp_path / "db.npy"


@pytest.mark.parametrize("name", ["m.npy", "m.csv", "m.h5"])
def test_a_model_name_of_another_format_is_refused(db: Path, tmp_path: Path, name: str) -> None:
    result = _invoke("train", db, "-o", tmp_path / name, "--method", "bruteforce")
    assert result.exit_code == 2, result.output
    assert "writes a model file (.npz)" in result.output and f"name it e.g. {tmp_path / 'm.npz'}" in result.output
    assert not (tmp_path / name).exists()


@pytest.mark.parametrize("name", ["m.npz", "m.btel"])  # a model is read by its content: other names still work
def test_a_model_name_of_no_other_format_is_written(db: Path, tmp_path: Path, name: str) -> None:
    assert _invoke("train", db, "-o", tmp_path / name, "--method", "bruteforce").exit_code == 0
    assert (tmp_path / name).is_file()


def test_a_folder_of_images_names_btel_extract(tmp_path: Path) -> None:
    images = tmp_path / "summer"
    images.mkdir()
    for name in ("images-00020.png", "images-00010.png"):
        (images / name).write_bytes(b"\x89PNG")  # not read: the names are enough
    result = _invoke("train", images, "-o", tmp_path / "m.npz")
    assert result.exit_code == 2, result.output
    assert f"DB {images} holds images (2, e.g. images-00010.png), not descriptors" in result.output
    assert f"`btel extract {images} -o descriptors.npy`" in result.output
    (images / "shard_0.npy").write_bytes(b"")  # shards beside images: read as shards (and refused as such)
    assert "holds images" not in _invoke("train", images, "-o", tmp_path / "m.npz").output


@pytest.mark.parametrize("command", ["train", "extract"])
def test_a_param_without_equals_sign_says_how_to_write_it(db: Path, tmp_path: Path, command: str) -> None:
    source = db if command == "train" else tmp_path
    result = _invoke(command, source, "-o", tmp_path / "x.npz", "--param", "n_regions", "5")
    assert result.exit_code == 2
    assert "--param takes KEY=VALUE (e.g. --param n_regions=5)." in result.output
    other = _invoke(command, source, "-o", tmp_path / "x.npz", "extra")  # no --param: click's words alone
    assert other.exit_code == 2 and "unexpected extra argument" in other.output and "KEY=VALUE" not in other.output


def test_demo_says_how_to_write_a_param_too() -> None:
    result = _invoke("demo", "--param", "n_regions", "5")
    assert result.exit_code == 2 and "--param takes KEY=VALUE (e.g. --param n_regions=5)." in result.output


def test_a_model_trained_without_a_budget_says_so(db: Path, tmp_path: Path) -> None:
    unbudgeted = _invoke("train", db, "-o", tmp_path / "a.npz", "--no-progress")
    assert unbudgeted.exit_code == 0 and "no --budget: the model is as large as the method needs" in unbudgeted.output
    budgeted = _invoke("train", db, "-o", tmp_path / "b.npz", "--budget", "2KB", "--no-progress")
    assert budgeted.exit_code == 0 and "no --budget" not in budgeted.output


def test_a_fit_without_bars_of_its_own_shows_the_time_elapsed_on_a_terminal() -> None:
    """auto fitted a 10⁴ × 16,384 map for a minute without a word: the elapsed time is shown, then
    cleared; with --no-progress nothing is written (off a terminal: the next test)."""
    import io
    import time

    from btel.core.progress import elapsed_ticker

    class Terminal(io.StringIO):
        def isatty(self) -> bool:
            return True

    shown = Terminal()
    with elapsed_ticker("fitting auto on 10000 × 16384", True, file=shown):
        time.sleep(1.2)
    frames = shown.getvalue().split("\r")
    assert "fitting auto on 10000 × 16384 … 00:01" in frames and frames[-2].strip() == ""
    silent = io.StringIO()
    with elapsed_ticker("fitting", False, file=silent):
        pass
    assert silent.getvalue() == ""


def test_an_output_that_is_one_of_the_inputs_is_refused_even_with_overwrite(tmp_path: Path) -> None:
    """`btel train dbz.npz -o dbz.npz --overwrite` replaced the map descriptors with the model."""
    from click.testing import CliRunner

    from btel.cli import main
    from btel.datasets import synthetic_route

    r = synthetic_route(100, 16, seed=0)
    both = tmp_path / "dbz.npz"
    np.savez(both, map=r.map, q=r.queries)
    before = both.read_bytes()
    runner = CliRunner()
    result = runner.invoke(main, ["train", f"{both}:map", "-o", str(both), "--overwrite"])
    assert result.exit_code == 2 and f"-o {both} is also the input DB" in result.output
    assert both.read_bytes() == before
    # The calibration queries are inputs too; another name is written as before.
    result = runner.invoke(main, ["train", f"{both}:map", "-o", str(both), "--overwrite", "--calibrate", f"{both}:q",
                                  "--calibrate-truth", str(tmp_path / "none.npy")])
    assert result.exit_code == 2 and both.read_bytes() == before
    assert runner.invoke(main, ["train", f"{both}:map", "-o", str(tmp_path / "m.npz")]).exit_code == 0


def test_a_fit_in_a_log_says_the_time_elapsed_now_and_then(monkeypatch) -> None:
    """A 33 s PQ fit of a wide map wrote nothing to a log: off a terminal the ticker writes a line every
    LINE_EVERY_SECONDS (here shortened), and none for a fit shorter than that."""
    import io
    import time

    from btel.core import progress

    monkeypatch.setattr(progress, "LINE_EVERY_SECONDS", 0.2)
    log = io.StringIO()
    with progress.elapsed_ticker("fitting pq on 500 × 8192", True, file=log):
        time.sleep(0.5)
    lines = log.getvalue().splitlines()
    assert len(lines) >= 2 and all(line == "fitting pq on 500 × 8192: 0:00 elapsed" for line in lines)
    assert "\r" not in log.getvalue()
    quick = io.StringIO()
    monkeypatch.setattr(progress, "LINE_EVERY_SECONDS", 10.0)
    with progress.elapsed_ticker("fitting", True, file=quick):
        pass
    assert quick.getvalue() == ""
