"""``btel localize`` writes image names beside the indices when its inputs name their rows."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from btel import load
from btel.cli import main

h5py = pytest.importorskip("h5py")


def _invoke(*args) -> "click.testing.Result":  # noqa: F821
    return CliRunner().invoke(main, [str(a) for a in args])


def _rows(path: Path) -> list[dict[str, str]]:
    with open(path, newline="", encoding="utf-8") as fh:
        return list(csv.DictReader(fh))


def _hloc_file(path: Path, X: np.ndarray, Q: np.ndarray) -> tuple[list[str], list[str]]:
    """hloc's usual layout: map and queries in one file, under db/ and query/."""
    db = [f"db/place_{i:03d}.jpg" for i in range(len(X))]
    queries = [f"query/frame_{j:03d}.jpg" for j in range(len(Q))]
    with h5py.File(path, "w") as fh:
        for name, x in [*zip(db, X), *zip(queries, Q)]:
            fh.create_group(name).create_dataset("global_descriptor", data=x)
    return db, queries


@pytest.mark.realdata
def test_localize_on_an_hloc_file_writes_query_and_place_names(gardenspoint_netvlad, tmp_path: Path) -> None:
    X, Q = (a[:100] for a in gardenspoint_netvlad)  # the first 100 places: a few seconds
    feats = tmp_path / "feats.h5"
    db_names, q_names = _hloc_file(feats, X, Q)
    model, out = tmp_path / "m.npz", tmp_path / "p.csv"
    assert _invoke("train", f"{feats}:db/", "-o", model, "--method", "bruteforce").exit_code == 0
    result = _invoke("localize", model, f"{feats}:query/", "--db", f"{feats}:db/", "-o", out, "--top-k", "3")
    assert result.exit_code == 0, result.output
    assert "with query and map image names" in result.output
    rows = _rows(out)
    assert list(rows[0]) == ["query", "prediction", "query_name", "prediction_name", "rank_1", "rank_2", "rank_3"]
    predictions = load(model).predict(Q)
    assert [int(r["prediction"]) for r in rows] == predictions.tolist()
    assert [r["query_name"] for r in rows] == q_names
    assert [r["prediction_name"] for r in rows] == [db_names[p] for p in predictions]
    assert np.mean(predictions == np.arange(len(Q))) > 0.1  # exact place, day vs night: 10x chance (1/100)


def test_query_names_alone_and_a_db_that_does_not_match(tmp_path: Path) -> None:
    rng = np.random.default_rng(0)
    X = rng.standard_normal((20, 8)).astype(np.float32)
    feats = tmp_path / "feats.h5"
    _, q_names = _hloc_file(feats, X, X[:5] + 0.01)
    model = tmp_path / "m.npz"
    assert _invoke("train", f"{feats}:db/", "-o", model, "--method", "bruteforce").exit_code == 0
    result = _invoke("localize", model, f"{feats}:query/", "-o", tmp_path / "a.csv")
    assert result.exit_code == 0, result.output
    rows = _rows(tmp_path / "a.csv")
    assert list(rows[0]) == ["query", "prediction", "query_name"] and [r["query_name"] for r in rows] == q_names
    # --db naming 5 images for a 20-place model: refused before writing, as an input error.
    result = _invoke("localize", model, f"{feats}:query/", "--db", f"{feats}:query/", "-o", tmp_path / "b.csv")
    assert result.exit_code == 2 and "names 5 images, but MODEL has 20 places" in result.output
    assert not (tmp_path / "b.csv").exists()
    # A matrix of the right length without names: the missing names are the problem, not the count.
    np.save(tmp_path / "map.npy", X)
    result = _invoke("localize", model, f"{feats}:query/", "--db", tmp_path / "map.npy", "-o", tmp_path / "b.csv")
    assert result.exit_code == 2 and "records no image names" in result.output and "PATH.json" in result.output
    np.save(tmp_path / "plain.npy", X[:5])  # no names recorded: numbers only, as before
    result = _invoke("localize", model, tmp_path / "plain.npy", "-o", tmp_path / "c.csv")
    assert result.exit_code == 0 and list(_rows(tmp_path / "c.csv")[0]) == ["query", "prediction"]


@pytest.mark.realdata
def test_localize_names_from_btel_extract(gardenspoint_sample_dir: Path, tmp_path: Path) -> None:
    """Descriptors written by `btel extract` name their images in the .json beside them."""
    db, q, model, out = (tmp_path / n for n in ("db.npy", "q.npy", "m.npz", "p.csv"))
    for folder, target in (("ref", db), ("query", q)):
        result = _invoke("extract", gardenspoint_sample_dir / folder, "-o", target, "--no-progress")
        assert result.exit_code == 0, result.output
    assert _invoke("train", db, "-o", model, "--method", "bruteforce").exit_code == 0
    assert _invoke("localize", model, q, "--db", db, "-o", out).exit_code == 0
    rows = _rows(out)
    ref = sorted(p.name for p in (gardenspoint_sample_dir / "ref").iterdir())
    assert {r["query_name"] for r in rows} == {p.name for p in (gardenspoint_sample_dir / "query").iterdir()}
    assert all(r["prediction_name"] == sorted(ref, key=lambda n: int(n.split(".")[0]))[int(r["prediction"])]
               for r in rows)


# -- what a newcomer gets wrong, refused in the command line's words ------------------------------------------
@pytest.fixture()
def small_model(bruteforce_files) -> tuple[Path, Path, Path]:
    """A 60-place bruteforce model of 16-value descriptors, its map and a noisy copy as queries."""
    return bruteforce_files(60, 16, "m.npz")


@pytest.mark.parametrize("name", ["p.npy", "p.tsv", "p"])
def test_an_output_name_of_another_format_is_refused(small_model, tmp_path: Path, name: str) -> None:
    _, q, model = small_model
    result = _invoke("localize", model, q, "-o", tmp_path / name)
    assert result.exit_code == 2 and "writes a predictions CSV (.csv or .txt)" in result.output
    assert f"name it e.g. {tmp_path / 'p.csv'}" in result.output and not (tmp_path / name).exists()
    assert _invoke("localize", model, q, "-o", tmp_path / "p.txt").exit_code == 0  # CSV text, as before
    assert (tmp_path / "p.txt").read_text().startswith("query,prediction")


def test_a_descriptor_matrix_given_as_model_is_named(small_model, tmp_path: Path) -> None:
    db, q, _ = small_model
    np.savez(tmp_path / "db.npz", X=np.load(db))
    for as_model in (db, tmp_path / "db.npz"):  # a .npy, and an .npz of numpy's, not btel's
        for args in ([q, "-o", tmp_path / "p.csv"], ["--stream"]):
            result = _invoke("localize", as_model, *args)
            assert result.exit_code == 2, result.output
            assert f"MODEL {as_model} looks like a descriptor matrix (60 × 16 float32)" in result.output
            assert "the .npz written by `btel train` (usage: btel localize MODEL QUERIES" in result.output
    (tmp_path / "junk.npz").write_bytes(b"not a model at all")  # not descriptors either: the load error stands
    result = _invoke("localize", tmp_path / "junk.npz", q, "-o", tmp_path / "p.csv")
    assert result.exit_code == 2 and "not a btel model file" in result.output


def test_sequence_filter_and_query_width_are_named_in_cli_words(small_model, tmp_path: Path) -> None:
    _, q, model = small_model
    for window in ("0", "-3"):
        result = _invoke("localize", model, q, "-o", tmp_path / "p.csv", "--sequence-filter", window)
        assert result.exit_code == 2
        assert f"--sequence-filter must be an integer ≥ 1 (the window in places); got {window}." in result.output
    np.save(tmp_path / "wide.npy", np.ones((5, 20), np.float32))
    result = _invoke("localize", model, tmp_path / "wide.npy", "-o", tmp_path / "p.csv")
    assert result.exit_code == 2 and "Q has" not in result.output
    assert (f"queries {tmp_path / 'wide.npy'} have 20 values per row, but MODEL was fitted on 16-value "
            "descriptors; extract the queries with the same descriptor") in result.output
    assert not (tmp_path / "p.csv").exists()


def test_the_message_says_which_names_were_written(tmp_path: Path) -> None:
    rng = np.random.default_rng(0)
    X = rng.standard_normal((20, 8)).astype(np.float32)
    feats = tmp_path / "feats.h5"
    _hloc_file(feats, X, X[:5] + 0.01)
    model = tmp_path / "m.npz"
    assert _invoke("train", f"{feats}:db/", "-o", model, "--method", "bruteforce").exit_code == 0
    result = _invoke("localize", model, f"{feats}:query/", "-o", tmp_path / "a.csv")
    assert "5 predictions with query image names written" in result.output and "give --db MAP" in result.output
    result = _invoke("localize", model, f"{feats}:query/", "--db", f"{feats}:db/", "-o", tmp_path / "b.csv")
    assert "with query and map image names written" in result.output and "give --db" not in result.output


def test_hmm_speed_reaches_the_decoder_in_batch_and_stream(gardenspoint_netvlad, tmp_path: Path) -> None:
    import btel

    db, queries = gardenspoint_netvlad
    Q = queries[::2]  # queries at every 2nd map frame: 0 … 4 places a frame, beyond the default speed
    np.save(tmp_path / "db.npy", db)
    np.save(tmp_path / "q.npy", Q)
    np.savetxt(tmp_path / "q.txt", Q)
    assert _invoke("train", tmp_path / "db.npy", "-o", tmp_path / "m.npz", "--method", "bruteforce",
                   "--no-progress").exit_code == 0
    model = btel.load(tmp_path / "m.npz")
    expected = model.predict_sequence(Q, "hmm", vmax=4)
    result = _invoke("localize", tmp_path / "m.npz", tmp_path / "q.npy", "-o", tmp_path / "p.csv", "--hmm",
                     "--hmm-speed", "4")
    assert result.exit_code == 0, result.output
    np.testing.assert_array_equal([int(r["prediction"]) for r in _rows(tmp_path / "p.csv")], expected)
    streamed = _invoke("localize", tmp_path / "m.npz", "--stream", "--input", tmp_path / "q.txt", "--hmm",
                       "--hmm-speed", "4")
    np.testing.assert_array_equal([int(x) for x in streamed.stdout.split()], expected)
    # The speed matters on these queries: the default (2) loses most of what speed 4 finds.
    truth = np.arange(0, len(db), 2)
    within = {speed: np.mean(np.abs(model.predict_sequence(Q, "hmm", vmax=speed) - truth) <= 2) for speed in (2, 4)}
    assert within[4] > within[2] + 0.3, within
    refused = _invoke("localize", tmp_path / "m.npz", tmp_path / "q.npy", "-o", tmp_path / "x.csv", "--hmm-speed", "4")
    assert refused.exit_code == 2 and "give --hmm too" in refused.output


def test_a_query_file_over_the_memory_limit_is_answered_in_row_blocks(tmp_path: Path, monkeypatch) -> None:
    """A float32 query file is memory-mapped and answered block by block: the limit applies to what is
    held, not to the file (it refused a 625 MiB file while fitting a map that size went through)."""
    import btel
    import btel.cli.localize as cli_localize
    from btel.datasets import synthetic_route

    route = synthetic_route(300, 64, seed=0)
    btel.make_method("lsh", budget="8KB").fit(route.map).save(tmp_path / "m.npz")
    Q = np.concatenate([route.queries] * 20)  # 6,000 × 64 float32: 1.5 MiB
    np.save(tmp_path / "q.npy", Q)
    monkeypatch.setenv("BTEL_MEMORY_LIMIT", "1M")
    monkeypatch.setattr(cli_localize, "_QUERY_BLOCK_BYTES", 100_000)  # 390 rows a block
    done = CliRunner().invoke(main, ["localize", str(tmp_path / "m.npz"), str(tmp_path / "q.npy"), "-o",
                                     str(tmp_path / "p.csv"), "--top-k", "3"])
    assert done.exit_code == 0, done.output
    with open(tmp_path / "p.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    model = load(tmp_path / "m.npz")
    np.testing.assert_array_equal([int(r["prediction"]) for r in rows], model.predict(Q))
    np.testing.assert_array_equal([[int(r[f"rank_{k}"]) for k in (1, 2, 3)] for r in rows], model.rank(Q, 3))


def test_localize_and_evaluate_write_one_predictions_layout(tmp_path: Path) -> None:
    """`btel localize` had a CSV writer of its own (names before ranks, \\r\\n lines); evaluate's put ranks first."""
    import csv

    from btel.datasets import synthetic_route

    r = synthetic_route(80, 16, seed=1)
    np.save(tmp_path / "db.npy", r.map)
    np.save(tmp_path / "q.npy", r.queries)
    runner = CliRunner()
    assert runner.invoke(main, ["train", str(tmp_path / "db.npy"), "--method", "bruteforce",
                                "-o", str(tmp_path / "m.npz")]).exit_code == 0
    result = runner.invoke(main, ["localize", str(tmp_path / "m.npz"), str(tmp_path / "q.npy"), "--top-k", "3",
                                  "-o", str(tmp_path / "p.csv")])
    assert result.exit_code == 0, result.output
    result = runner.invoke(main, ["evaluate", "--model", str(tmp_path / "m.npz"), "--queries", str(tmp_path / "q.npy"),
                                  "--k", "1,3", "--no-progress", "--out", str(tmp_path / "run")])
    assert result.exit_code == 0, result.output
    mine = list(csv.DictReader(open(tmp_path / "p.csv", newline="")))
    theirs = list(csv.DictReader(open(tmp_path / "run" / "predictions_m.csv", newline="")))
    assert list(mine[0]) == ["query", "prediction", "rank_1", "rank_2", "rank_3"]
    assert list(theirs[0])[:2] == ["query", "prediction"] and list(theirs[0])[-3:] == ["rank_1", "rank_2", "rank_3"]
    assert [{k: row[k] for k in mine[0]} for row in theirs] == mine
    assert b"\r\n" not in (tmp_path / "p.csv").read_bytes()


def test_a_slow_batch_shows_its_progress_and_answers_as_one_block(tmp_path: Path, monkeypatch) -> None:
    """`btel localize` of 500 queries on an 8192-sub-quantiser PQ was silent for 15 s: a batch whose rest
    would take more than _QUIET_SECONDS (here 0) is answered in timed blocks under a bar (a line in a log,
    here every 0 s); the predictions and rankings are those of one call. --no-progress: no line."""
    from btel.cli import localize as localize_cli
    from btel.core import progress
    from btel.datasets import synthetic_route

    route = synthetic_route(300, 32, seed=3)
    model = load(_fit_and_save(route.map, tmp_path / "m.btel.npz"))
    np.save(tmp_path / "q.npy", route.queries)
    monkeypatch.setattr(localize_cli, "_QUIET_SECONDS", 0.0)
    monkeypatch.setattr(localize_cli, "_BLOCK_SECONDS", 0.0)  # blocks of 7 rows: the 64-row probe, then 34 blocks
    monkeypatch.setattr(localize_cli, "_MIN_BLOCK_ROWS", 7)
    monkeypatch.setattr(progress, "LINE_EVERY_SECONDS", 0.0)
    shown = _invoke("localize", tmp_path / "m.btel.npz", tmp_path / "q.npy", "-o", tmp_path / "p.csv", "--top-k", 3)
    assert shown.exit_code == 0, shown.output
    assert "localizing: 300/300 queries done" in shown.stderr and "ranking: 300/300 queries done" in shown.stderr
    rows = _rows(tmp_path / "p.csv")
    np.testing.assert_array_equal([int(r["prediction"]) for r in rows], model.predict(route.queries))
    np.testing.assert_array_equal([[int(r[f"rank_{k}"]) for k in (1, 2, 3)] for r in rows],
                                  model.rank(route.queries, 3))
    quiet = _invoke("localize", tmp_path / "m.btel.npz", tmp_path / "q.npy", "-o", tmp_path / "p2.csv",
                    "--no-progress")
    assert quiet.exit_code == 0 and "queries done" not in quiet.stderr


def _fit_and_save(X: np.ndarray, path: Path) -> Path:
    import btel

    btel.make_method("lsh", budget=4_000, random_state=0).fit(X).save(path)
    return path


def test_a_query_file_declaring_more_answers_than_memory_holds_is_refused_before_it_is_read(
        small_model, tmp_path: Path, monkeypatch) -> None:
    """A sparse .npy of 10¹⁰ × 64 queries made `btel localize` check values for minutes while its resident
    memory grew to 20 GB (and `btel train` on 10⁹ × 4096 rows alike): the header's row count is checked
    first — the answers table against the machine's memory (here said to be 100 MB) for localize, the
    model's places against the memory limit for train. Sparse files: no disk used."""
    import time

    from btel.core import limits

    monkeypatch.setattr(limits, "physical_memory", lambda: 100_000_000)

    def sparse(path: Path, rows: int) -> Path:
        with open(path, "wb") as fh:
            np.lib.format.write_array_header_1_0(fh, {"descr": "<f4", "fortran_order": False, "shape": (rows, 1)})
            fh.truncate(fh.tell() + 4 * rows)  # as long as the header says: not a file cut short
        return path

    model = small_model[2]
    start = time.perf_counter()
    refused = _invoke("localize", model, sparse(tmp_path / "q.npy", 40_000_000), "-o", tmp_path / "p.csv")
    assert refused.exit_code != 0 and "40,000,000 queries" in refused.output
    assert "this machine has 95.4 MiB" in refused.output and not (tmp_path / "p.csv").exists()
    refused = _invoke("train", sparse(tmp_path / "db.npy", 10_000_000), "-o", tmp_path / "m.btel.npz",
                      "--method", "lsh", "--budget", "1MB")
    assert refused.exit_code != 0 and "N = 10000000 places" in refused.output
    assert time.perf_counter() - start < 30  # bounded: nothing was read past the header


def test_top_k_is_checked_before_the_answers_it_would_size(small_model, tmp_path: Path) -> None:
    """--top-k 10¹¹ on a 60-place model was refused as 218 TiB of answers, not as a rank beyond the map."""
    _, queries, model = small_model
    refused = _invoke("localize", model, queries, "-o", tmp_path / "p.csv", "--top-k", 10**11)
    assert refused.exit_code == 2 and "give --top-k between 1 and 60" in refused.output
