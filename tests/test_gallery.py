"""Match gallery (btel.evaluation.gallery, `btel evaluate` on image inputs, `btel show RUN`) and image names in
the predictions files."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from btel.cli import main
from btel.exceptions import InvalidParameterError
from btel.evaluation.gallery import choose_gallery_queries, plot_match_gallery


def _rows(path: Path) -> list[dict[str, str]]:
    with open(path, newline="", encoding="utf-8") as fh:
        return list(csv.DictReader(fh))


def test_gallery_queries_mix_failures_and_successes_deterministically() -> None:
    correct = np.zeros(100, dtype=bool)
    correct[::3] = True  # 34 right, 66 wrong
    chosen = choose_gallery_queries(correct, 8)
    assert chosen.tolist() == choose_gallery_queries(correct, 8).tolist()
    assert chosen.size == 8 and correct[chosen].sum() == 4 and np.all(np.diff(chosen) > 0)
    assert chosen.max() > 80 and chosen.min() < 10  # spread over the route, not its first queries
    # Too few of one kind: the other fills the rows; never more rows than queries.
    one_right = np.array([False] * 9 + [True])
    assert correct_count(one_right, 8) == (8, 1)
    assert choose_gallery_queries(np.ones(3, dtype=bool), 8).tolist() == [0, 1, 2]
    with pytest.raises(InvalidParameterError, match="n_rows"):
        choose_gallery_queries(correct, 0)


def correct_count(correct: np.ndarray, n: int) -> tuple[int, int]:
    chosen = choose_gallery_queries(correct, n)
    return chosen.size, int(correct[chosen].sum())


def test_gallery_refuses_disagreeing_inputs(tmp_path: Path) -> None:
    with pytest.raises(InvalidParameterError, match="2 query images but 3 predictions"):
        plot_match_gallery(["a", "b"], ["c"], np.zeros(3), np.zeros(3), np.zeros(3, bool), tmp_path / "g.png")
    with pytest.raises(InvalidParameterError, match="outside the 1 map images"):
        plot_match_gallery(["a"], ["c"], np.array([4]), np.zeros(1), np.zeros(1, bool), tmp_path / "g.png")


def _extract(runner: CliRunner, folder: Path, out: Path) -> None:
    result = runner.invoke(main, ["extract", str(folder), "-o", str(out), "--descriptor", "patchnorm",
                                  "--size", "56x32", "--no-progress"])
    assert result.exit_code == 0, result.output


@pytest.mark.realdata
def test_evaluate_on_images_names_predictions_and_draws_gallery(gardenspoint_sample_dir: Path,
                                                               tmp_path: Path) -> None:
    import matplotlib.image as mpimg

    runner = CliRunner()
    db, q = tmp_path / "db.npy", tmp_path / "q.npy"
    _extract(runner, gardenspoint_sample_dir / "ref", db)
    _extract(runner, gardenspoint_sample_dir / "query", q)
    assert json.loads(Path(str(db) + ".json").read_text())["folder"] == str((gardenspoint_sample_dir / "ref").resolve())
    run = tmp_path / "run"
    result = runner.invoke(main, ["evaluate", "--db", str(db), "--queries", str(q), "--methods", "bruteforce",
                                  "--no-progress", "--out", str(run)])
    assert result.exit_code == 0, result.output
    rows = _rows(run / "predictions_bruteforce.csv")
    n = len(list((gardenspoint_sample_dir / "query").glob("*.jpg")))
    assert len(rows) == n
    for r in rows:  # row numbers stay; names are the image files of those rows
        assert r["query_name"] == f"{r['query']}.jpg" and r["prediction_name"] == f"{r['prediction']}.jpg"
        assert r["true_name"] == f"{r['true']}.jpg" and r["correct"] == str(int(r["prediction"] == r["true"]))
    gallery = run / "gallery_bruteforce.png"
    assert f"match gallery: {gallery}" in result.output
    image = mpimg.imread(gallery)
    shown = min(n, 8)
    assert image.shape[0] > shown * 150 and image.shape[1] >= 600  # one row of three images per query
    # Red and green frames: the run has failures, and each frame colour is drawn for what it judged.
    n_ok = sum(r["correct"] == "1" for r in rows)
    red = np.all(np.abs(image[..., :3] - np.array([0xd7, 0x19, 0x1c]) / 255) < 0.02, axis=-1).sum()
    green = np.all(np.abs(image[..., :3] - np.array([0x1a, 0x96, 0x41]) / 255) < 0.02, axis=-1).sum()
    assert (red > 0) == (n_ok < n) and (green > 0) == (n_ok > 0)

    # btel show describes the run and keeps the gallery evaluate drew (it failed with "already exists");
    # a missing one it draws again from the finished run folder.
    drawn = gallery.read_bytes()
    kept = runner.invoke(main, ["show", str(run)])
    assert kept.exit_code == 0, kept.output
    assert f"gallery: {gallery} (kept; --overwrite draws it again)" in kept.output and gallery.read_bytes() == drawn
    assert "command: " in kept.output and f"input --db: {db}" in kept.output and "bruteforce*" in kept.output
    gallery.unlink()
    shown_again = runner.invoke(main, ["show", str(run), "--rows", "4"])
    assert shown_again.exit_code == 0, shown_again.output
    assert gallery.is_file() and mpimg.imread(gallery).shape[0] < image.shape[0]


@pytest.mark.realdata
def test_show_says_why_without_images(gardenspoint_netvlad: tuple[np.ndarray, np.ndarray], tmp_path: Path) -> None:
    X, Q = gardenspoint_netvlad
    db, q = tmp_path / "db.npy", tmp_path / "q.npy"
    np.save(db, X[:50])
    np.save(q, Q[:50])
    run = tmp_path / "run"
    runner = CliRunner()
    result = runner.invoke(main, ["evaluate", "--db", str(db), "--queries", str(q), "--methods", "bruteforce",
                                  "--no-progress", "--out", str(run)])
    assert result.exit_code == 0, result.output
    assert not list(run.glob("gallery_*")) and "query_name" not in (run / "predictions_bruteforce.csv").read_text()
    shown = runner.invoke(main, ["show", str(run)])  # the run is shown; why there is no gallery is said
    assert shown.exit_code == 0 and "no match gallery:" in shown.output and "record none on disk" in shown.output
    assert "Traceback" not in shown.output and "bruteforce*" in shown.output
    missing = runner.invoke(main, ["show", str(tmp_path / "nowhere")])
    assert missing.exit_code == 2 and "no metrics.json" in missing.output


def test_show_on_a_demo_run_says_it_has_no_images(tmp_path: Path) -> None:
    """A run no input file of the user's made (btel demo): it is said to have no images, not that the
    --db and --queries "not given" record none."""
    runner = CliRunner()
    assert runner.invoke(main, ["demo", "--places", "100", "--dim", "16", "--methods", "lsh", "--budget", "1KB", "--no-progress", "--out", str(tmp_path / "demo")]).exit_code == 0
    shown = runner.invoke(main, ["show", str(tmp_path / "demo")])
    assert shown.exit_code == 0 and "records no input files" in shown.output and "not given" not in shown.output
    assert "data: synthetic_route (generated by btel" in shown.output and "lsh" in shown.output


@pytest.mark.realdata
def test_positives_ground_truth_names_a_positive(gardenspoint_sample_dir: Path, tmp_path: Path) -> None:
    """UTM positives (VPR-methods-evaluation names): the predictions name a positive of each query and
    say whether the top-1 is one; the gallery shows that positive as the true place."""
    from btel.datasets.vpr_names import utm_from_name

    data = tmp_path / "gp"
    for sub, src in (("database", "ref"), ("queries", "query")):
        (data / sub).mkdir(parents=True)
        for image in sorted((gardenspoint_sample_dir / src).glob("*.jpg")):
            (data / sub / f"@{500000 + 10 * int(image.stem):.2f}@4000000.00@55@H@@.jpg").symlink_to(image)
    runner = CliRunner()
    db, q = tmp_path / "db.npy", tmp_path / "q.npy"
    _extract(runner, data / "database", db)
    _extract(runner, data / "queries", q)
    run = tmp_path / "run"
    result = runner.invoke(main, ["evaluate", "--db", str(db), "--queries", str(q), "--methods", "bruteforce",
                                  "--ground-truth", "utm", "--query-order", "independent", "--no-progress",
                                  "--out", str(run)])
    assert result.exit_code == 0, result.output
    rows = _rows(run / "predictions_bruteforce.csv")
    for r in rows:
        east = utm_from_name(r["query_name"])[0]
        assert abs(utm_from_name(r["positive_name"])[0] - east) <= 25
        assert r["correct"] == str(int(abs(utm_from_name(r["prediction_name"])[0] - east) <= 25))
    metrics = json.loads((run / "metrics.json").read_text())
    assert metrics["results"][0]["recall_at_k"]["1"] == pytest.approx(np.mean([r["correct"] == "1" for r in rows]))
    assert (run / "gallery_bruteforce.png").is_file()


@pytest.mark.realdata
def test_hloc_group_names_in_predictions(gardenspoint_netvlad: tuple[np.ndarray, np.ndarray], tmp_path: Path) -> None:
    h5py = pytest.importorskip("h5py")
    X, Q = gardenspoint_netvlad
    path = tmp_path / "global-feats.h5"
    with h5py.File(path, "w") as fh:
        for prefix, rows in (("db", X[:30]), ("query", Q[:30])):
            for i, x in enumerate(rows):
                fh.create_group(f"{prefix}/{i:03d}.png").create_dataset("global_descriptor", data=x)
    run = tmp_path / "run"
    result = CliRunner().invoke(main, ["evaluate", "--db", f"{path}:db/", "--queries", f"{path}:query/", "--methods",
                                       "bruteforce", "--no-progress", "--out", str(run)])
    assert result.exit_code == 0, result.output
    rows = _rows(run / "predictions_bruteforce.csv")
    assert len(rows) == 30
    for r in rows:
        assert r["query_name"].endswith(f"{int(r['query']):03d}.png")
        assert r["prediction_name"].endswith(f"{int(r['prediction']):03d}.png")
        assert r["true_name"].endswith(f"{int(r['true']):03d}.png")
    assert not list(run.glob("gallery_*"))  # names, but no image files to show


@pytest.mark.realdata
def test_unreadable_image_warns_and_keeps_the_run(gardenspoint_sample_dir: Path, tmp_path: Path) -> None:
    """The run is written before the gallery; an image that cannot be decoded costs the figure only."""
    folder = tmp_path / "ref"
    folder.mkdir()
    for image in (gardenspoint_sample_dir / "ref").glob("*.jpg"):
        (folder / image.name).write_bytes(image.read_bytes())
    runner = CliRunner()
    db, q = tmp_path / "db.npy", tmp_path / "q.npy"
    _extract(runner, folder, db)
    _extract(runner, gardenspoint_sample_dir / "query", q)
    for image in folder.glob("*.jpg"):
        image.write_bytes(b"not a jpeg")  # damaged after extraction
    run = tmp_path / "run"
    result = runner.invoke(main, ["evaluate", "--db", str(db), "--queries", str(q), "--methods", "bruteforce",
                                  "--no-progress", "--out", str(run)])
    assert result.exit_code == 0, result.output
    assert "match gallery could not be drawn" in result.output and "cannot decode" in result.output
    assert (run / "metrics.json").is_file() and not list(run.glob("gallery_*"))


@pytest.mark.realdata
def test_extraction_before_the_folder_was_recorded_is_reused_and_completed(gardenspoint_sample_dir: Path,
                                                                          tmp_path: Path) -> None:
    runner = CliRunner()
    db = tmp_path / "db.npy"
    _extract(runner, gardenspoint_sample_dir / "ref", db)
    sidecar = Path(str(db) + ".json")
    old = json.loads(sidecar.read_text())
    del old["folder"]  # as written by the previous version
    sidecar.write_text(json.dumps(old))
    again = runner.invoke(main, ["extract", str(gardenspoint_sample_dir / "ref"), "-o", str(db), "--descriptor",
                                 "patchnorm", "--size", "56x32", "--no-progress"])
    assert again.exit_code == 0 and "already exists" not in again.output, again.output
    assert json.loads(sidecar.read_text())["folder"] == str((gardenspoint_sample_dir / "ref").resolve())


# -- issue 34, item 3: names in galleries ------------------------------------------------------------------
def _image_run(tmp_path: Path, names: list[str]) -> tuple[Path, Path]:
    """Descriptors written by `btel extract` from a folder of tiny images named ``names``, as map and
    queries of one finished run."""
    import cv2

    folder = tmp_path / "images"
    folder.mkdir()
    for i, name in enumerate(names):
        # Textured, not flat: patch normalisation makes flat images of any grey the same descriptor.
        cv2.imwrite(str(folder / name), np.random.default_rng(i).integers(0, 256, (32, 56), dtype=np.uint8))
    db = tmp_path / "db.npy"
    _extract(CliRunner(), folder, db)
    run = tmp_path / "run"
    result = CliRunner().invoke(main, ["evaluate", "--db", str(db), "--queries", str(db), "--methods",
                                       "bruteforce", "--no-reference", "--no-progress", "--out", str(run)])
    assert result.exit_code == 0, result.output
    return db, run


def test_a_dollar_in_an_image_name_is_drawn_as_text(tmp_path: Path) -> None:
    """A file named like TeX (``$\\frac$``) made matplotlib's mathtext raise while drawing."""
    db, run = _image_run(tmp_path, ["0.png", "1$\\frac$.png", "2.png"])
    assert (run / "gallery_bruteforce.png").is_file()


def test_a_gallery_opens_only_images_inside_the_recorded_folder(tmp_path: Path) -> None:
    db, run = _image_run(tmp_path, ["0.png", "1.png", "2.png"])
    secret = tmp_path / "secret.png"
    secret.write_bytes((tmp_path / "images" / "0.png").read_bytes())
    sidecar = Path(str(db) + ".json")
    key = json.loads(sidecar.read_text())
    key["images"][1][0] = "../secret.png"  # an edited .json pointing outside its folder
    sidecar.write_text(json.dumps(key))
    result = CliRunner().invoke(main, ["show", str(run), "--overwrite"])
    assert result.exit_code == 2 and isinstance(result.exception, SystemExit), result.output
    error = result.output.strip().splitlines()[-1]  # after the run's description, one line of error
    assert result.output.count("Error:") == 1 and error.startswith("Error:")
    assert "'../secret.png' (row 1) is not a plain file name" in error


def test_the_gallery_title_is_wrapped_inside_the_figure(gardenspoint_sample_dir: Path, tmp_path: Path,
                                                        monkeypatch) -> None:
    """Its one long line ran past both edges of the 9-inch figure."""
    import matplotlib.pyplot as plt

    kept = []
    monkeypatch.setattr(plt, "close", kept.append)  # look at the figure the function drew
    images = sorted((gardenspoint_sample_dir / "ref").glob("*.jpg"))
    n = len(images)
    plot_match_gallery(images, images, np.arange(n), np.arange(n), np.arange(n) % 2 == 0, tmp_path / "g.png",
                       title="lsh — a run folder with a long name")
    fig = kept[0]
    fig.canvas.draw()
    box = fig._suptitle.get_window_extent()
    assert 0 <= box.x0 and box.x1 <= fig.bbox.width
    assert all(ax.get_position().y1 <= box.y0 / fig.bbox.height for ax in fig.axes)  # no row under it
