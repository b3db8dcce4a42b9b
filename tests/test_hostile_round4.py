"""Hostile inputs, round 4: records edited into other types, options at values that never end, numpy
subclasses, files that read without end or fail to read, and archives whose directory lies about its size.
Each case ends with one error naming the input and the fix (exit 2 from the CLI), in bounded time.
"""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest
from click.testing import CliRunner

from btel.cli import main
from btel.datasets.row_names import row_images, row_names
from btel.exceptions import InvalidDescriptorsError


@pytest.mark.parametrize("field, value", [("folder", 5), ("folder", ["a"]), ("folder", {}), ("folder", True),
                                          ("folder", "/" + "a" * 5000), ("images", [{"name": "00.png"}]),
                                          ("images", "00.png"), ("images", [[1, 2, 3]])])
def test_a_record_edited_into_other_types_is_named_not_a_traceback(extracted, tmp_path: Path, field: str,
                                                                   value: object) -> None:
    """``"folder": 5`` gave a TypeError traceback from evaluate and show; image entries that were objects
    dropped the names silently; a string of images gave one-letter names."""
    _, out = extracted
    sidecar = Path(str(out) + ".json")
    record = json.loads(sidecar.read_text())
    record[field] = value
    sidecar.write_text(json.dumps(record))
    with pytest.raises(InvalidDescriptorsError, match=r"db\.npy\.json: .*(edited or damaged)"):
        row_images(out) if field == "folder" else row_names(out)
    result = CliRunner().invoke(main, ["evaluate", "--db", str(out), "--queries", str(out),
                                       "--methods", "lsh", "--budget", "1KB", "--no-progress", "--out",
                                       str(tmp_path / "run")])
    if field == "images":  # the names are read before the run: refused
        assert result.exit_code == 2 and "edited or damaged" in result.output, result.output
        return
    # The folder is read for the gallery once the run is written: the run stands, the gallery is refused.
    assert result.exit_code == 0 and "gallery could not be drawn" in result.output and "edited or damaged" in result.output
    shown = CliRunner().invoke(main, ["show", str(tmp_path / "run")])
    assert shown.exit_code == 2 and "edited or damaged" in shown.output and "Traceback" not in shown.output


@pytest.mark.parametrize("value", ["nan", "inf", "-1", "0", "1e20"])
def test_an_idle_timeout_that_never_ends_or_ends_at_once_is_a_usage_error(tmp_path: Path, value: str) -> None:
    """``--follow --idle-timeout nan`` (or inf) followed the file forever; -1 stopped at once."""
    from btel.methods import make_method

    make_method("lsh", budget="1KB").fit(np.eye(8, dtype=np.float32)).save(tmp_path / "m.npz")
    (tmp_path / "q.txt").write_text("1,0,0,0,0,0,0,0\n")
    result = CliRunner().invoke(main, ["localize", str(tmp_path / "m.npz"), "--stream", "--input",
                                       str(tmp_path / "q.txt"), "--follow", "--idle-timeout", value])
    assert result.exit_code == 2 and "--idle-timeout must be a number of seconds above 0 and below 10⁹" in result.output


@pytest.mark.parametrize("value", ["99999999999999999999", str((1 << 30) + 1)])
def test_a_line_limit_beyond_a_gibibyte_is_named(monkeypatch, value: str) -> None:
    """A 20-digit ``BTEL_MAX_LINE_BYTES`` ended the stream with a bare OverflowError from readline."""
    from btel.exceptions import InvalidParameterError
    from btel.sequence.lineparse import max_line_bytes

    monkeypatch.setenv("BTEL_MAX_LINE_BYTES", value)
    with pytest.raises(InvalidParameterError, match=r"BTEL_MAX_LINE_BYTES must be a number of bytes from 1 to .*Unset it"):
        max_line_bytes()


@pytest.mark.filterwarnings("ignore::PendingDeprecationWarning")  # numpy's own, on np.asmatrix
@pytest.mark.parametrize("method", ["lsh", "btel-codes", "rabitq", "bruteforce", "pq"])
def test_a_numpy_matrix_is_read_as_its_rows(method: str) -> None:
    """``np.matrix`` kept its subclass through validation and failed inside numpy ('shapes not aligned')."""
    from btel.methods import make_method

    X = np.random.default_rng(0).standard_normal((300, 16)).astype(np.float32)
    seed = {} if method == "bruteforce" else {"random_state": 0}
    plain = make_method(method, budget="32KB", **seed).fit(X)
    matrix = make_method(method, budget="32KB", **seed).fit(np.asmatrix(X))
    np.testing.assert_array_equal(matrix.predict(np.asmatrix(X[:20])), plain.predict(X[:20]))


@pytest.mark.skipif(not Path("/proc/self/pagemap").exists(), reason="needs Linux /proc")
@pytest.mark.parametrize("target, message", [("/proc/self/pagemap", "holds more than its size says"),
                                             ("/proc/self/mem", "could not be read")])
def test_an_image_that_reads_without_end_or_fails_to_read_is_named(tmp_path: Path, monkeypatch, target: str,
                                                                  message: str) -> None:
    """A kernel file says it holds 0 bytes: pagemap then reads on for gigabytes, mem fails with EIO. Both
    gave a bare OSError (no file named) from btel extract."""
    from btel.core.limits import read_regular
    from btel.exceptions import BTELError

    monkeypatch.setenv("BTEL_MEMORY_LIMIT", "4M")
    folder = tmp_path / "imgs"
    folder.mkdir()
    cv2.imwrite(str(folder / "0.png"), np.zeros((32, 64), np.uint8))
    (folder / "1.png").symlink_to(target)
    with pytest.raises(BTELError, match=message):
        read_regular(folder / "1.png", "image")
    result = CliRunner().invoke(main, ["extract", str(folder), "-o", str(tmp_path / "d.npy"), "--no-progress"])
    assert result.exit_code == 2 and "1.png" in result.output and message in result.output, result.output


def _archive_of(path: Path, members: int) -> Path:
    import zipfile

    with zipfile.ZipFile(path, "w") as archive:
        for i in range(members):
            archive.writestr(f"{i:07d}.npy", b"")
    return path


@pytest.mark.parametrize("role", ["model", "descriptors", "ground truth"])
def test_an_archive_listing_too_many_members_is_refused_before_its_directory_is_parsed(tmp_path: Path, monkeypatch,
                                                                                     role: str) -> None:
    """10⁶ central-directory entries (57 MB) were parsed whole (18 s, 1.1 GB) before the member limit was
    checked; and the limit was charged as bytes, so raising BTEL_MEMORY_LIMIT let the file through."""
    import zipfile

    from btel.core.limits import MAX_ZIP_MEMBERS
    from btel.exceptions import BTELError

    path = _archive_of(tmp_path / "many.npz", MAX_ZIP_MEMBERS + 1)
    parsed: list[object] = []
    real = zipfile.ZipFile
    monkeypatch.setattr(zipfile, "ZipFile", lambda *a, **kw: (parsed.append(a), real(*a, **kw))[1])
    monkeypatch.setenv("BTEL_MEMORY_LIMIT", "64G")  # a count, not bytes: the limit does not let it through
    if role == "model":
        from btel.methods import load

        call = lambda: load(path)  # noqa: E731
    elif role == "descriptors":
        from btel.descriptors import load_descriptor_matrix

        call = lambda: load_descriptor_matrix(path)  # noqa: E731
    else:
        from btel.datasets import GroundTruth

        call = lambda: GroundTruth.from_file(path)  # noqa: E731
    with pytest.raises(BTELError, match=f"lists {MAX_ZIP_MEMBERS + 1:,} archive members"):
        call()
    assert parsed == []
    result = CliRunner().invoke(main, ["info", str(path)])
    assert result.exit_code == 2 and "archive members" in result.output


def _tiled_tiff(path: Path, size: int, tile: int) -> Path:
    """A greyscale TIFF of ``size``² pixels in ``tile``² tiles (one tile of four bytes: the header is what counts)."""
    import struct

    entries = [(256, 3, size), (257, 3, size), (258, 3, 8), (259, 3, 1), (262, 3, 1), (277, 3, 1),
               (322, 4, tile), (323, 4, tile), (324, 4, 8 + 2 + 12 * 10 + 4), (325, 4, 4)]
    ifd = struct.pack("<H", len(entries)) + b"".join(struct.pack("<HHII", tag, kind, 1, value)
                                                      if kind == 4 else struct.pack("<HHIHH", tag, kind, 1, value, 0)
                                                      for tag, kind, value in entries) + struct.pack("<I", 0)
    path.write_bytes(b"II*\x00" + struct.pack("<I", 8) + ifd + b"\x00" * 4)
    return path


def test_a_tiff_tile_larger_than_its_image_is_counted_by_the_decode_bound(tmp_path: Path) -> None:
    """A 16×16 TIFF in 16000×16000 tiles (995 KB) took 1.2 GB: OpenCV allocates a whole tile before libtiff checks it."""
    from btel.descriptors.images import read_image
    from btel.exceptions import ResourceLimitError

    (tmp_path / "imgs").mkdir()
    path = _tiled_tiff(tmp_path / "imgs" / "a.tif", 16, 16000)
    with pytest.raises(ResourceLimitError, match=r"16×16 in 16000×16000 tiles"):
        read_image(path)
    result = CliRunner().invoke(main, ["extract", str(tmp_path / "imgs"), "-o", str(tmp_path / "d.npy"), "--no-progress"])
    assert result.exit_code == 2 and "16000×16000 tiles" in result.output


def test_shards_claiming_more_rows_than_the_disk_holds_are_refused_before_merging(tmp_path: Path) -> None:
    """Two sparse shards (4 KB on disk each) claiming 2.5·10⁶ … rows were merged into a 2 GB file in /tmp with no
    check of the room there; larger claims would fill the disk."""
    import shutil

    from btel.datasets import load_shards
    from btel.exceptions import ResourceLimitError

    rows = shutil.disk_usage(tmp_path).free // (4 * 100) + 1  # one row more than the disk holds
    (tmp_path / "shards").mkdir()
    for i in range(2):
        with open(tmp_path / "shards" / f"s{i}.npy", "wb") as fh:
            np.lib.format.write_array_header_1_0(fh, {"descr": "<f4", "fortran_order": False, "shape": (rows, 100)})
            fh.truncate(fh.tell() + rows * 400)  # sparse: no disk used
    with pytest.raises(ResourceLimitError, match=r"merged into one float32 map .* free"):
        load_shards(tmp_path / "shards", tmp_dir=tmp_path)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["shards"]  # nothing written


def test_a_csv_line_of_more_positives_than_csv_reads_in_one_field_names_the_fix(tmp_path: Path) -> None:
    """30,000 positives on one line: csv's 131,072-character field limit surfaced as a bare csv.Error."""
    from btel.datasets import GroundTruth
    from btel.exceptions import DataNotFoundError

    path = tmp_path / "gt.csv"
    path.write_text("query,positives\n0," + " ".join(str(i) for i in range(30_000)) + "\n")
    with pytest.raises(DataNotFoundError, match=r"gt\.csv' line 2: .*one pair per line instead"):
        GroundTruth.from_file(path)
    path.write_text("query,positive\n" + "".join(f"0,{i}\n" for i in range(30_000)))  # the fix it names
    assert GroundTruth.from_file(path).positives(0).size == 30_000


@pytest.mark.filterwarnings("error")
def test_float16_place_indices_read_without_an_overflow_warning(tmp_path: Path) -> None:
    """float16 ``query_places`` warned of an overflow (2⁶² compared in float16), refused under -W error."""
    from btel.datasets import GroundTruth

    np.savez(tmp_path / "gt.npz", query_places=np.arange(50, dtype=np.float16), n_map=np.int64(60))
    assert GroundTruth.from_file(tmp_path / "gt.npz").query_places.tolist() == list(range(50))


def test_opq_nested_parameters_reach_the_default_quantiser() -> None:
    """The docstring's own ``OPQLocalizer().set_params(pq__nbits=4)`` raised AttributeError on pq=None, and
    ``make_method("opq", pq__nbits=4)`` was refused."""
    from btel.exceptions import InvalidParameterError
    from btel.methods import make_method
    from btel.methods.baselines.opq import OPQLocalizer
    from btel.methods.baselines.pq import PQLocalizer

    assert OPQLocalizer().set_params(pq__nbits=4).pq.get_params()["nbits"] == 4
    model = make_method("opq", budget="8KB", pq__nbits=4)
    assert isinstance(model.pq, PQLocalizer) and model.pq.nbits == 4
    X = np.random.default_rng(0).standard_normal((300, 32)).astype(np.float32)
    assert model.fit(X).config_.nbits == 4
    with pytest.raises(InvalidParameterError, match="has no parameter 'pq__bogus'"):
        make_method("opq", pq__bogus=1)
    with pytest.raises(InvalidParameterError, match="invalid parameter 'budget__x'|no parameters to set"):
        OPQLocalizer().set_params(budget__x=1)


def test_a_map_of_scaled_copies_of_one_row_is_refused_as_one_descriptor(tmp_path) -> None:
    """Scaled copies of one vector (or a width-1 map of positive values) passed the distinct-rows check on the raw
    rows, then became one descriptor under the L2 front end: every query got one place, exit 0."""
    import btel
    from btel.exceptions import InvalidDescriptorsError

    v = np.random.default_rng(0).standard_normal(64).astype(np.float32)
    scaled = v[None] * np.linspace(1, 5, 200, dtype=np.float32)[:, None]
    width_one = np.random.default_rng(1).uniform(1, 2, (50, 1)).astype(np.float32)
    for X in (scaled, width_one):
        for name in ("auto", "bruteforce", "lsh", "btel-codes"):
            with pytest.raises(InvalidDescriptorsError, match="points the same way"):
                btel.make_method(name).fit(X)
        # Lengths are what differs: with normalize='none' they are places again.
        btel.make_method("bruteforce", normalize="none").fit(X)
    mixed = scaled.copy()
    mixed[-1] = -mixed[-1]  # one row the other way: two directions, a map (however poor)
    btel.make_method("bruteforce").fit(mixed)
    np.save(tmp_path / "scaled.npy", scaled)
    result = CliRunner().invoke(main, ["train", str(tmp_path / "scaled.npy"), "-o", str(tmp_path / "m.npz")])
    assert result.exit_code == 2 and "every row of the map points the same way" in result.output
    assert "--param normalize=none" in result.output
