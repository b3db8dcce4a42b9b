"""A researcher's own descriptor and ground-truth files, round 2: each case either works or is refused
with one line naming the problem and the fix (exit 2, no traceback), and nothing is ever unpickled."""

from __future__ import annotations

import os
import pickle
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from btel.cli import main
from btel.datasets import GroundTruth
from btel.descriptors.npy_header import check_npy_header, npy_header
from btel.exceptions import DataNotFoundError, InvalidDescriptorsError, InvalidParameterError

N, D = 40, 16


class _Evil:
    """Unpickling this runs code: it creates the file named ``marker``."""

    def __init__(self, marker: Path) -> None:
        self.marker = marker

    def __reduce__(self):  # noqa: ANN204
        return (os.system, (f"touch {self.marker}",))


@pytest.fixture()
def files(tmp_path: Path) -> dict[str, Path]:
    rng = np.random.default_rng(0)
    X = rng.standard_normal((N, D)).astype(np.float32)
    Q = (X + 0.05 * rng.standard_normal((N, D))).astype(np.float32)
    out = {"db": tmp_path / "db.npy", "q": tmp_path / "q.npy", "marker": tmp_path / "PWNED"}
    np.save(out["db"], X)
    np.save(out["q"], Q)
    out["obj"] = tmp_path / "obj.npy"
    np.save(out["obj"], np.array([_Evil(out["marker"]), 1], dtype=object), allow_pickle=True)
    out["lie"] = tmp_path / "lie.npy"  # a header announcing 15 GiB in front of 2.5 KiB of data
    with open(out["lie"], "wb") as fh:
        np.lib.format.write_array_header_1_0(fh, {"descr": "<f4", "fortran_order": False, "shape": (10**6, 4096)})
        fh.write(X.tobytes())
    out["cut"] = tmp_path / "cut.npy"  # a copy that stopped half way
    data = out["db"].read_bytes()
    out["cut"].write_bytes(data[: len(data) // 2])
    return out


def _refused(args: list[str], *words: str) -> str:
    result = CliRunner().invoke(main, args)
    assert result.exit_code == 2, (result.exit_code, result.output, result.exception)
    errors = [line for line in result.output.splitlines() if line.startswith("Error:")]
    assert len(errors) == 1 and "Traceback" not in result.output, result.output
    for word in words:
        assert word in errors[0], errors[0]
    return errors[0]


def _commands(tmp: Path, bad: Path, good_db: Path, good_q: Path) -> list[list[str]]:
    model = tmp / "bf.npz"
    if not model.exists():
        assert CliRunner().invoke(main, ["train", str(good_db), "--method", "bruteforce", "-o", str(model)]).exit_code == 0
    return [
        ["train", str(bad), "--method", "bruteforce", "-o", str(tmp / "m.npz")],
        ["localize", str(model), str(bad), "-o", str(tmp / "p.csv")],
        ["evaluate", "--db", str(bad), "--queries", str(good_q), "--methods", "bruteforce", "--no-reference",
         "--out", str(tmp / "run"), "--no-progress"],
        ["evaluate", "--db", str(good_db), "--queries", str(bad), "--methods", "bruteforce", "--no-reference",
         "--out", str(tmp / "run"), "--no-progress"],
    ]


# -- descriptor files --------------------------------------------------------------------------------
def test_object_npy_is_refused_as_a_pickle_by_every_command(tmp_path: Path, files: dict[str, Path]) -> None:
    """`btel train` memory-maps the map, and numpy's map said "Array can't be memory-mapped"."""
    for args in _commands(tmp_path, files["obj"], files["db"], files["q"]):
        _refused(args, "Python objects", "never unpickles", "np.save")
    assert not files["marker"].exists()


def test_a_header_announcing_more_than_the_file_holds_is_named(tmp_path: Path, files: dict[str, Path]) -> None:
    """Was "mmap length is greater than file size" (train) or "would need 15.3 GiB … raise the limit"
    (localize, evaluate), which sends the user after the memory limit."""
    for bad in (files["lie"], files["cut"]):
        for args in _commands(tmp_path, bad, files["db"], files["q"]):
            message = _refused(args, "cut short", "header announces", "write the file again")
            assert "BTEL_MEMORY_LIMIT" not in message


def test_a_header_of_absurd_size_is_named_without_overflow_warnings(tmp_path: Path) -> None:
    path = tmp_path / "huge.npy"
    with open(path, "wb") as fh:
        np.lib.format.write_array_header_1_0(fh, {"descr": "<f4", "fortran_order": False, "shape": (10**15, 10**6)})
        fh.write(b"\0" * 64)
    result = CliRunner().invoke(main, ["train", str(path), "-o", str(tmp_path / "m.npz")])
    assert result.exit_code == 2 and "cut short" in result.output and "overflow" not in result.output.lower()


def test_a_cut_short_shard_is_named(tmp_path: Path, files: dict[str, Path]) -> None:
    shards = tmp_path / "shards"
    shards.mkdir()
    np.save(shards / "shard_0.npy", np.load(files["db"]))
    (shards / "shard_1.npy").write_bytes(files["cut"].read_bytes())
    _refused(["train", str(shards), "--method", "bruteforce", "-o", str(tmp_path / "m.npz")],
             "shard_1.npy", "cut short")


def test_check_npy_header_leaves_good_and_foreign_files_to_the_reader(tmp_path: Path, files: dict[str, Path]) -> None:
    check_npy_header(files["db"], "map")  # complete: nothing to say
    (tmp_path / "x.csv").write_text("1,2\n3,4\n")
    check_npy_header(tmp_path / "x.csv", "map")  # not an .npy: numpy's reader names it
    check_npy_header(tmp_path, "map")  # a folder: the reader names it
    check_npy_header(files["obj"], "ground truth", objects=True)  # VPR-Bench's object arrays are parsed elsewhere
    fortran = tmp_path / "f.npy"
    np.save(fortran, np.asfortranarray(np.ones((5, 3), ">f8")))
    check_npy_header(fortran, "map")
    assert npy_header(fortran)[:3] == ((5, 3), np.dtype(">f8"), 120)
    with pytest.raises(InvalidDescriptorsError, match="Python objects"):
        check_npy_header(files["obj"], "map")
    with pytest.raises(InvalidDescriptorsError, match="cut short"):
        check_npy_header(files["cut"], "map")
    assert not files["marker"].exists()


@pytest.mark.parametrize("dtype", ["float16", "float64", "int8", "uint8", ">f4", "bool"])
def test_other_dtypes_and_layouts_still_train_and_localize(tmp_path: Path, files: dict[str, Path],
                                                           dtype: str) -> None:
    X, Q = np.load(files["db"]), np.load(files["q"])
    scale = 1 if dtype.startswith(("f", ">")) else 40
    db, q = tmp_path / "db_x.npy", tmp_path / "q_x.npy"
    if dtype == "bool":
        np.save(db, np.asfortranarray(X > 0))
        np.save(q, Q > 0)
    else:
        np.save(db, np.asfortranarray(np.clip(X * scale + (100 if dtype == "uint8" else 0), -127, 255).astype(dtype)))
        np.save(q, np.clip(Q * scale + (100 if dtype == "uint8" else 0), -127, 255).astype(dtype))
    model = tmp_path / "m.npz"
    assert CliRunner().invoke(main, ["train", str(db), "--method", "bruteforce", "-o", str(model)]).exit_code == 0
    result = CliRunner().invoke(main, ["localize", str(model), str(q), "-o", str(tmp_path / "p.csv")])
    assert result.exit_code == 0, result.output
    rows = (tmp_path / "p.csv").read_text().splitlines()[1:]
    predicted = np.array([int(r.split(",")[1]) for r in rows])
    assert np.mean(predicted == np.arange(N)) >= 0.9


# -- ground truth --------------------------------------------------------------------------------------
def _evaluate_gt(tmp: Path, files: dict[str, Path], gt: Path) -> list[str]:
    return ["evaluate", "--db", str(files["db"]), "--queries", str(files["q"]), "--methods", "bruteforce",
            "--no-reference", "--ground-truth", str(gt), "--out", str(tmp / "run"), "--overwrite", "--no-progress"]


def test_positives_that_name_no_place_for_any_query_are_refused(tmp_path: Path, files: dict[str, Path]) -> None:
    """A CSV listing every query with an empty cell crashed the evaluation with 'IndexError: index 0 is out
    of bounds' (every metric would be 0 anyway)."""
    gt = tmp_path / "gt.csv"
    gt.write_text("query,positives\n" + "".join(f"{i},\n" for i in range(N)))
    _refused(_evaluate_gt(tmp_path, files, gt), "none of its 40 queries", "positive")
    with pytest.raises(InvalidParameterError, match="none of its"):
        GroundTruth.from_file(gt)


def test_some_queries_without_positives_still_run(tmp_path: Path, files: dict[str, Path]) -> None:
    gt = tmp_path / "gt.csv"
    gt.write_text("query,positive\n" + "".join(f"{i},{i}\n" for i in range(N) if i != 3))
    result = CliRunner().invoke(main, _evaluate_gt(tmp_path, files, gt))
    assert result.exit_code == 0, result.output


def test_utm_positives_with_nobody_in_range_are_refused() -> None:
    from btel.datasets.groundtruth_files import check_some_positive

    gt = GroundTruth.from_utm(np.zeros((5, 2)), np.full((3, 2), 1000.0), 25)
    with pytest.raises(InvalidParameterError, match="radius"):
        check_some_positive(gt, "the UTM ground truth")


def test_an_npz_with_two_layouts_is_refused(tmp_path: Path, files: dict[str, Path]) -> None:
    """query_places and indptr/indices in one file: the CSR arrays were used silently."""
    gt = tmp_path / "gt.npz"
    np.savez(gt, query_places=np.arange(N), indptr=np.arange(N + 1), indices=(np.arange(N) + 5) % N)
    _refused(_evaluate_gt(tmp_path, files, gt), "2 ground-truth layouts", "query_places", "indptr+indices")


def test_npy_of_whole_floats_is_read_like_the_npz_and_fractions_are_refused(tmp_path: Path,
                                                                            files: dict[str, Path]) -> None:
    whole, frac = tmp_path / "whole.npy", tmp_path / "frac.npy"
    np.save(whole, np.arange(N, dtype=np.float64))  # MATLAB and pandas write indices as doubles
    np.save(frac, np.arange(N) + 0.5)
    assert CliRunner().invoke(main, _evaluate_gt(tmp_path, files, whole)).exit_code == 0
    assert GroundTruth.from_file(whole).query_places.dtype == np.int64
    _refused(_evaluate_gt(tmp_path, files, frac), "whole numbers")
    nan = tmp_path / "nan.npy"
    np.save(nan, np.r_[np.arange(N - 1.0), np.nan])
    _refused(_evaluate_gt(tmp_path, files, nan), "whole numbers")


def test_a_pickle_as_ground_truth_is_refused_without_numpys_advice(tmp_path: Path, files: dict[str, Path]) -> None:
    """numpy's message said 'you can load it unsafely using the allow_pickle= keyword argument'."""
    for name in ("gt.pkl", "gt.npy"):
        gt = tmp_path / name
        with open(gt, "wb") as fh:
            pickle.dump(_Evil(files["marker"]), fh)
        message = _refused(_evaluate_gt(tmp_path, files, gt), "never unpickles")
        assert "allow_pickle" not in message and "unsafely" not in message
    assert not files["marker"].exists()


def test_a_cut_short_ground_truth_is_named(tmp_path: Path, files: dict[str, Path]) -> None:
    """Was 'would need 7.5 GiB' or 'holds pickled objects or is not numpy data'."""
    lie, cut = tmp_path / "lie.npy", tmp_path / "cut.npy"
    with open(lie, "wb") as fh:
        np.lib.format.write_array_header_1_0(fh, {"descr": "<i8", "fortran_order": False, "shape": (10**9,)})
        fh.write(np.arange(N).tobytes())
    np.save(cut, np.arange(N))
    cut.write_bytes(cut.read_bytes()[:-16])
    for gt in (lie, cut):
        message = _refused(_evaluate_gt(tmp_path, files, gt), "cut short")
        assert "pickle" not in message and "BTEL_MEMORY_LIMIT" not in message
        with pytest.raises(DataNotFoundError, match="cut short"):
            GroundTruth.from_file(gt)


# -- text matrices --------------------------------------------------------------------------------------
@pytest.mark.parametrize(("name", "write", "options"), [
    ("x.txt", lambda p, X: np.savetxt(p, X), ""),
    ("x.csv", lambda p, X: np.savetxt(p, X, delimiter=","), "delimiter=','"),
    ("x.csv", lambda p, X: np.savetxt(p, X, delimiter=",", header="a,b", comments=""), "skiprows=1"),
    ("x.npy", lambda p, X: np.savetxt(p, X, delimiter=","), "delimiter=','"),  # a CSV under a .npy name
    # A European spreadsheet export: ';' between values, ',' as the decimal mark.
    ("x.csv", lambda p, X: p.write_text("\n".join(";".join(f"{v:.9g}".replace(".", ",") for v in row) for row in X)
                                        + "\n"), "delimiter=';'"),
    # A Unicode minus (U+2212), with a byte-order mark and a header line.
    ("x.csv", lambda p, X: p.write_text("\ufeffa,b\n" + "\n".join(",".join(f"{v:.9g}".replace("-", "\u2212")
                                        for v in row) for row in X) + "\n", encoding="utf-8"), "skiprows=1"),
])
def test_a_text_matrix_is_refused_with_the_command_that_converts_it(tmp_path: Path, files: dict[str, Path],
                                                                    name: str, write, options: str) -> None:
    X = np.load(files["db"])
    path = tmp_path / name
    write(path, X)
    message = _refused(["train", str(path), "--method", "bruteforce", "-o", str(tmp_path / "m.npz")],
                       "text matrix", options)
    command = message.split('python -c "', 1)[1].rstrip('"')
    exec(command, {})  # noqa: S102 - the command the message gives, as a user would paste it
    target = path.with_name(path.stem + (".float32.npy" if path.suffix == ".npy" else ".npy"))
    np.testing.assert_allclose(np.load(target), X, rtol=1e-6)
    result = CliRunner().invoke(main, ["train", str(target), "--method", "bruteforce", "-o", str(tmp_path / "m.npz")])
    assert result.exit_code == 0, result.output


def test_binary_files_under_a_npy_name_keep_their_message(tmp_path: Path, files: dict[str, Path]) -> None:
    png = tmp_path / "image.npy"
    png.write_bytes(b"\x89PNG\r\n\x1a\n" + bytes(range(256)))
    message = _refused(["train", str(png), "-o", str(tmp_path / "m.npz")], "not a .npy file")
    assert "is a text matrix" not in message


def test_the_python_loader_names_a_cut_short_file_a_pickle_and_a_text_matrix(tmp_path: Path,
                                                                             files: dict[str, Path]) -> None:
    """``load_descriptor_matrix`` (memory-mapped or not) says what the command line says, not numpy's words."""
    from btel.descriptors import load_descriptor_matrix

    for mmap_mode in (None, "r"):
        for key, words in (("cut", "cut short"), ("lie", "cut short"), ("obj", "Python objects")):
            with pytest.raises(InvalidDescriptorsError, match=words) as err:
                load_descriptor_matrix(files[key], mmap_mode=mmap_mode)
            assert "mmap length" not in str(err.value) and "BTEL_MEMORY_LIMIT" not in str(err.value)
    text = tmp_path / "x.csv"
    np.savetxt(text, np.load(files["db"]), delimiter=",")
    with pytest.raises(InvalidDescriptorsError, match="text matrix.*delimiter=','"):
        load_descriptor_matrix(text)
    assert not files["marker"].exists()


def test_a_fifo_is_named_a_fifo_and_a_loop_of_links_a_link(tmp_path) -> None:
    """A FIFO was called a folder, and a loop of links a file that does not exist."""
    import os

    from btel.core.modelfile import load_arrays
    from btel.descriptors import load_descriptor_matrix
    from btel.exceptions import DataNotFoundError, ModelFileError

    os.mkfifo(tmp_path / "f.npy")
    with pytest.raises(DataNotFoundError, match="not a regular file"):
        load_descriptor_matrix(tmp_path / "f.npy")
    (tmp_path / "a.npz").symlink_to(tmp_path / "b.npz")
    (tmp_path / "b.npz").symlink_to(tmp_path / "a.npz")
    with pytest.raises(DataNotFoundError, match="link that leads nowhere"):
        load_descriptor_matrix(tmp_path / "a.npz")
    with pytest.raises(ModelFileError, match="link that leads nowhere"):
        load_arrays(tmp_path / "a.npz")


def test_a_header_announcing_less_than_the_file_holds_is_named(tmp_path: Path) -> None:
    """numpy reads what the header says: 100 of 200 rows were used and the rest ignored, unsaid."""
    from btel.descriptors import load_descriptor_matrix
    from btel.exceptions import InvalidDescriptorsError

    X = np.random.default_rng(0).normal(size=(200, 64)).astype(np.float32)
    np.save(tmp_path / "half.npy", X[:100])
    with open(tmp_path / "half.npy", "ab") as fh:
        fh.write(X[100:].tobytes())
    with pytest.raises(InvalidDescriptorsError, match=r"more than the .* its shape \(100, 64\)"):
        load_descriptor_matrix(tmp_path / "half.npy")
