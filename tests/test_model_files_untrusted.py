"""A model file is untrusted input (issue #13): every numbered item of the issue has its tests here.

The fuzz harness over all of these at once is ``tests/test_fuzz_model_files.py``.
"""

from __future__ import annotations

import io
import json
import struct
import threading
import zipfile
from pathlib import Path
from typing import Any, Callable

import numpy as np
import pytest
from click.testing import CliRunner

import btel
from btel.core import modelfile
from btel.cli import main
from btel.datasets import synthetic_route
from btel.exceptions import (
    BTELError,
    InvalidDescriptorsError,
    InvalidParameterError,
    ModelFileError,
    NotEnoughPlacesError,
    NotFittedError,
)
from btel.methods import make_method
from btel.core.modelfile import HEADER_KEY, load_arrays

N_PLACES, DIM = 64, 16

#: Small fitted models, one per case below (name → (method, parameters, fit with two traverses)).
FIXTURES: dict[str, tuple[str, dict[str, Any], bool]] = {
    "btel-c": ("btel-c", {"progress": False}, False),
    "btel-f": ("btel-f", {"progress": False}, False),
    "btel-r": ("btel-c", {"n_regions": 3, "progress": False}, False),
    "btel-whiten": ("btel-c", {"whiten": 8, "progress": False}, False),
    "ryth": ("ryth", {}, False),
    "bruteforce": ("bruteforce", {}, False),
    "bruteforce-places": ("bruteforce", {}, True),
    "pq": ("pq", {}, False),
    "pq-pca": ("pq", {"pca_dim": 8}, False),
    "opq": ("opq", {}, False),
    "itq": ("itq", {}, False),
    "seqslam": ("seqslam", {}, False),
}


@pytest.fixture(scope="module")
def route():
    return synthetic_route(N_PLACES, DIM, n_regions=3, seed=5)


@pytest.fixture(scope="module")
def files(route, tmp_path_factory) -> dict[str, Path]:
    folder = tmp_path_factory.mktemp("models")
    out = {}
    for name, (method, params, two_traverses) in FIXTURES.items():
        model = make_method(method, **params)
        if two_traverses:
            model.fit(np.concatenate([route.map, route.map[::-1] * 0.5 + route.map * 0.5]),
                      np.concatenate([np.arange(N_PLACES), np.arange(N_PLACES)]))
        else:
            model.fit(route.map)
        out[name] = model.save(folder / f"{name}.npz")
    return out


@pytest.fixture(scope="module")
def queries(route) -> np.ndarray:
    return route.queries[:8]


# ----------------------------------------------------------------------------- writing crafted files
def rewrite(src: Path, dst: Path, *, header: Callable[[dict], Any] | None = None,
            arrays: Callable[[dict], Any] | None = None, header_text: Callable[[str], str] | None = None) -> Path:
    """A copy of a model file with its JSON header and/or arrays edited (a valid zip otherwise)."""
    loaded, head = load_arrays(src)
    if header:
        header(head)
    if arrays:
        arrays(loaded)
    text = json.dumps(head)
    if header_text:
        text = header_text(text)
    members = [(HEADER_KEY + ".npy", npy(np.frombuffer(text.encode("utf-8"), dtype=np.uint8)))]
    members += [(f"{k}.npy", npy(v)) for k, v in loaded.items()]
    dst.write_bytes(zip_of(members))
    return dst


def npy(array: np.ndarray) -> bytes:
    buffer = io.BytesIO()
    np.lib.format.write_array(buffer, np.asarray(array), allow_pickle=False)
    return buffer.getvalue()


def raw_npy(header_text: str, payload: bytes, version: bytes = b"\x01\x00") -> bytes:
    """A .npy member with a header dict written by hand (numpy would not write these)."""
    text = header_text.encode("latin1") + b"\n"
    return b"\x93NUMPY" + version + struct.pack("<H", len(text)) + text + payload


def zip_of(members: list[tuple[str, bytes]], compress: dict[str, int] | None = None) -> bytes:
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w") as archive:
        for name, data in members:
            info = zipfile.ZipInfo(name, date_time=(1980, 1, 1, 0, 0, 0))
            info.compress_type = (compress or {}).get(name, zipfile.ZIP_STORED)
            archive.writestr(info, data)
    return buffer.getvalue()


def members_of(path: Path) -> list[tuple[str, bytes]]:
    with zipfile.ZipFile(path) as archive:
        return [(info.filename, archive.read(info)) for info in archive.infolist()]


def set_param(key: str, value: Any) -> Callable[[dict], Any]:
    return lambda h: h["params"].__setitem__(key, value)


def set_state(key: str, value: Any) -> Callable[[dict], Any]:
    return lambda h: h["state"].__setitem__(key, value)


def set_array(key: str, value: Callable[[np.ndarray], np.ndarray]) -> Callable[[dict], Any]:
    return lambda a: a.__setitem__(key, value(a[key]))


def assert_places_in_range(model, Q: np.ndarray) -> None:
    n = model.n_places_
    for places in (model.predict(Q), model.rank(Q, 3), model.predict_sequence(Q, "hmm")):
        assert places.dtype == np.int64 and places.min() >= 0 and places.max() < n


# ============================================================================= 1. header values
@pytest.mark.parametrize("name", ["pq", "opq", "itq", "bruteforce", "seqslam", "ryth", "btel-c"])
@pytest.mark.parametrize("n_jobs", [1_000_000_000, 33_571_696, 0, "all"])
def test_runtime_settings_in_a_file_are_not_restored(name, n_jobs, files, queries, tmp_path) -> None:
    """n_jobs = 10⁹ in a PQ file made `btel localize` abort in libgomp; 33571696 segfaulted."""
    path = rewrite(files[name], tmp_path / "m.npz", header=set_param("n_jobs", n_jobs))
    model = btel.load(path)
    assert model.n_jobs is None
    assert_places_in_range(model, queries)


def test_btel_runtime_settings_in_a_file_are_not_restored(files, queries, tmp_path) -> None:
    edit = lambda h: h["params"].update(backend="dask", scheduler="tcp://10.0.0.1:1", progress=True)  # noqa: E731
    model = btel.load(rewrite(files["btel-c"], tmp_path / "m.npz", header=edit))
    assert (model.backend, model.scheduler, model.progress) == (None, None, True)
    assert_places_in_range(model, queries)


def test_opq_nested_quantiser_runtime_settings_are_not_restored(files, queries, tmp_path) -> None:
    edit = set_param("pq", {"estimator": "PQLocalizer", "params": {"n_jobs": 10**9, "nbits": 4}})
    model = btel.load(rewrite(files["opq"], tmp_path / "m.npz", header=edit))
    assert model.pq.n_jobs is None
    assert_places_in_range(model, queries)


@pytest.mark.parametrize(
    ("name", "edit", "message"),
    [
        ("btel-c", set_param("code_copies", 10**6), "code_copies must be"),  # 238 s in load before
        ("btel-c", set_param("code_copies", 10**9), "code_copies must be"),
        ("btel-c", set_param("block_size", -1), "block_size must be"),
        ("btel-c", set_param("dtype", "complex64"), "dtype must be"),
        ("btel-c", set_param("scheme", ["compressed"]), "scheme must be"),
        ("ryth", set_state("n_places", 10**9), "periods"),  # predict ran for minutes before
        ("ryth", set_state("n_places", -3), "n_places = -3 is not an integer"),
        ("ryth", set_param("n_periods", 10**6), "n_periods must be"),
        ("seqslam", set_param("vmax", 3e6), "vmax must be"),  # predict ran for minutes before
        ("seqslam", set_param("vskip", 1e-300), "more than 1000 velocities"),
        ("seqslam", set_param("ds", 0), "ds must be"),
        ("pq", set_param("nbits", 100), "nbits must be"),
        ("pq", set_state("nbits", 100), "nbits = 100 is not an integer"),
        ("pq", set_state("n_subquantizers", 10**9), "n_subquantizers = 1000000000 is not an integer"),
        ("opq", set_param("n_iter", 10**9), "n_iter must be"),
        ("opq", set_param("pq", {"estimator": "OPQLocalizer", "params": {}}), "'pq' is not a PQLocalizer"),
        ("opq", set_param("pq", {"estimator": "PQLocalizer", "params": {"nbits": 100}}), "nbits must be"),
        ("itq", set_state("code_bits", 12), "not a multiple of 8"),
        ("btel-f", set_state("n_places", 2**32 - 1), "classifiers|BTEL_MEMORY_LIMIT"),  # hung building 2**32 tree nodes before
        ("btel-r", set_state("n_regions", 2**20), "n_regions = 1048576 is not an integer"),
        ("btel-c", set_state("n_features_in", 10**12), "n_features_in = 1000000000000 is not an integer"),
        ("btel-c", lambda h: h["state"]["front_end"].update(whiten=10**6), "whitening arrays do not match"),
        # A streamed query kept 2w copies of the first frame: 16 GB of references for w = 10⁹.
        ("btel-c", lambda h: h["state"]["front_end"].update(delta=10**9), "delta must be"),
        ("btel-c", set_state("n_places", 2**33), "n_places = 8589934592 is not an integer"),
        # `btel info` divided by a budget of 0.5 (read as 0 B), and showed "800000% used" for "1B".
        ("bruteforce", set_param("budget", 0.5), "less than one byte"),
        ("bruteforce", set_param("budget", "1e-300KB"), "less than one byte"),
        ("bruteforce", set_param("budget", "1B"), r"arrays take [\d,]+ B, over the budget of 1 B"),
        ("pq", set_param("budget", 100), r"arrays take [\d,]+ B, over the budget of 100 B"),
    ],
)
def test_header_values_are_checked_before_anything_is_computed(name, edit, message, files, tmp_path) -> None:
    with pytest.raises(ModelFileError, match=message):
        btel.load(rewrite(files[name], tmp_path / "m.npz", header=edit))


def test_seqslam_lines_longer_than_the_map_cost_no_more_than_the_map(files, queries, tmp_path) -> None:
    """vmax·ds far beyond the map asked for a (queries × vmax·ds) padding (745 GiB for ds = 10⁴, vmax = 10⁶)."""
    edit = lambda h: h["params"].update(ds=10_000, vmin=0.0, vmax=1e6, vskip=1e5)  # noqa: E731
    model = btel.load(rewrite(files["seqslam"], tmp_path / "m.npz", header=edit))
    assert_places_in_range(model, queries)


def test_sequence_costs_with_offsets_past_the_map_equal_the_loop() -> None:
    from btel.methods.baselines.seqslam import sequence_costs, velocities

    D = np.random.default_rng(0).random((7, 12))
    vs = velocities(0.0, 30.0, 7.5)  # offsets up to 30·6 = 180 map rows, the map has 12
    expected = np.full(D.shape, np.inf)
    for j in range(D.shape[0]):
        for e in range(D.shape[1]):
            for v in vs:
                total = sum(D[j - t, e - int(np.floor(v * t + 0.5))] if e - int(np.floor(v * t + 0.5)) >= 0
                            else D[j - t].mean() for t in range(min(7, j + 1)))
                expected[j, e] = min(expected[j, e], total)
    np.testing.assert_allclose(sequence_costs(D, 7, 0.0, 30.0, 7.5), expected, rtol=1e-5)


def test_velocities_are_counted_before_they_are_listed() -> None:
    from btel.methods.baselines.seqslam import velocities

    with pytest.raises(InvalidParameterError, match="more than 1000 velocities"):
        velocities(0.0, 1e6, 1e-300)


# ============================================================================= 2. arrays against each other
def _flip_sign(a: np.ndarray) -> np.ndarray:
    return a.astype(np.int16) * -1


@pytest.mark.parametrize(
    ("name", "header", "arrays", "message"),
    [
        ("btel-c", None, set_array("bias", lambda a: a[:-1]), "bias or columns do not hold one row"),
        ("btel-c", None, set_array("columns", lambda a: a[:, :-1]), "array 'columns' has shape"),
        ("btel-c", None, set_array("weights", lambda a: a[None]), "array 'weights' has shape"),
        ("btel-c", None, set_array("weights", lambda a: np.full_like(a, np.nan)), "NaN or infinite"),
        ("btel-c", None, set_array("bias", lambda a: np.full_like(a, np.inf)), "NaN or infinite"),
        ("btel-c", None, set_array("weights", lambda a: a.astype(np.complex64)), "dtype complex64"),
        ("btel-c", None, set_array("weights", lambda a: a.astype("<U8")), "dtype <U8"),
        ("btel-c", None, set_array("columns", _flip_sign), "array 'columns' has shape .* dtype int16"),
        ("btel-c", None, set_array("columns", lambda a: np.full_like(a, DIM)), "columns index past d"),
        ("btel-r", None, set_array("region_starts", lambda a: a[::-1].copy()), "region starts are not increasing"),
        ("btel-r", None, set_array("region_starts", lambda a: a + N_PLACES), "region starts"),
        ("btel-r", None, set_array("region_weights", lambda a: a[:1]), "array 'region_weights' has shape"),
        ("btel-f", None, set_array("weights", lambda a: a[:-1]), "classifiers; its regions imply"),
        ("btel-whiten", None, set_array("frontend_whitening", lambda a: a * np.nan), "NaN or infinite"),
        ("btel-whiten", None, set_array("frontend_mean", lambda a: a[:-1]), "whitening arrays do not match"),
        ("ryth", set_state("n_places", -3), None, "n_places = -3"),
        ("ryth", None, set_array("weights", lambda a: a[:-1]), "array 'weights' has shape"),
        ("ryth", None, set_array("columns", lambda a: np.full_like(a, 60000)), "columns index past d"),
        ("bruteforce", set_state("n_places", 10), None, "indexes 64 map rows but says N = 10"),
        ("bruteforce", None, set_array("descriptors", lambda a: a * np.float32(1e30)), "descriptors row 0 has length"),
        ("bruteforce", None, set_array("descriptors", lambda a: a * np.nan), "descriptors row 0 has length nan"),
        ("bruteforce-places", None, set_array("row_places", lambda a: a[:-1]), "row_places table does not fit"),
        ("bruteforce-places", None, set_array("row_places", lambda a: a + 1), "row_places table does not fit"),
        ("bruteforce-places", None, set_array("row_places", lambda a: a[:0]), "row_places table does not fit"),
        ("pq", None, set_array("codebooks", lambda a: np.full_like(a, np.nan)), "NaN, infinite"),
        ("pq", None, set_array("codes", lambda a: a[:-1]), "indexes 63 map rows but says N = 64"),
        ("pq-pca", None, set_array("projection", lambda a: a.T.copy()), "array 'projection' has shape"),
        # Loaded, then every query answered place −1 (found by the fuzz harness).
        ("pq-pca", None, set_array("projection", lambda a: a * np.float32(1e30)), "out-of-range"),
        ("opq", None, set_array("projection", lambda a: np.full_like(a, np.inf)), "NaN, infinite"),
        ("itq", None, set_array("mean", lambda a: a.astype(np.float64)), "array 'mean' has shape"),
        ("itq", None, lambda a: a.pop("codes"), "lacks the array 'codes'"),
        ("seqslam", None, set_array("value_range", lambda a: np.zeros_like(a)), "invalid value range"),
        ("seqslam", None, lambda a: a.update(extra=np.zeros(3)), "arrays \\['extra'\\]"),
    ],
)
def test_arrays_are_checked_against_the_state_and_each_other(name, header, arrays, message, files, tmp_path) -> None:
    with pytest.raises(ModelFileError, match=message):
        btel.load(rewrite(files[name], tmp_path / "m.npz", header=header, arrays=arrays))


@pytest.mark.parametrize("name", sorted(FIXTURES))
def test_a_loaded_model_answers_places_in_range(name, files, queries) -> None:
    assert_places_in_range(btel.load(files[name]), queries)


# ============================================================================= 3. nothing generic escapes
def test_a_flipped_byte_in_an_array_header_is_a_model_file_error(files, tmp_path) -> None:
    """numpy's header parser raised tokenize.TokenError."""
    members = members_of(files["btel-c"])
    name, _ = members[1]
    members[1] = (name, raw_npy("{'descr': '<f4', 'fortran_order': False, 'shape': (3,", b"\0" * 12))
    (tmp_path / "m.npz").write_bytes(zip_of(members))
    with pytest.raises(ModelFileError, match="corrupt header"):
        btel.load(tmp_path / "m.npz")


@pytest.mark.parametrize(
    ("header_text", "message"),
    [
        ("{'descr': '<f4', 'fortran_order': False, 'shape': (1000000000000,), }", "holds 12 B"),  # MemoryError
        ("{'descr': '<f4', 'fortran_order': False, 'shape': (10**30,), }", "corrupt header"),
        ("{'descr': '<f4', 'fortran_order': False, 'shape': (" + "9" * 5000 + ",), }", "longer than 4096 B"),
        ("{'descr': '<f4', 'fortran_order': False, 'shape': (" + "9" * 4000 + ",), }", "holds 12 B"),
        ("{'descr': '|O', 'fortran_order': False, 'shape': (3,), }", "pickled objects"),
        ("{'descr': '<c8', 'fortran_order': False, 'shape': (3,), }", "complex64"),
        ("{'descr': '<U1', 'fortran_order': False, 'shape': (3,), }", "<U1"),
        ("{'descr': [('a', '<f4')], 'fortran_order': False, 'shape': (3,), }", "dtype"),
        ("{'descr': '<f4', 'fortran_order': False, 'shape': (1, 1, 1, 1, 1, 1, 1, 1, 3), }", "shape"),
    ],
)
def test_array_headers_are_checked_before_anything_is_allocated(header_text, message, files, tmp_path) -> None:
    members = members_of(files["btel-c"])
    members.append(("extra.npy", raw_npy(header_text, b"\0" * 12)))
    (tmp_path / "m.npz").write_bytes(zip_of(members))
    with pytest.raises(ModelFileError, match=message):
        btel.load(tmp_path / "m.npz")


def test_an_unknown_npy_version_is_a_model_file_error(files, tmp_path) -> None:
    members = members_of(files["btel-c"])
    members.append(("extra.npy", raw_npy("{'descr': '<f4', 'fortran_order': False, 'shape': (3,), }", b"\0" * 12,
                                         version=b"\x09\x00")))
    (tmp_path / "m.npz").write_bytes(zip_of(members))
    with pytest.raises(ModelFileError, match="corrupt header"):
        btel.load(tmp_path / "m.npz")


@pytest.mark.filterwarnings("ignore:Duplicate name")
def test_members_that_are_not_arrays(files, tmp_path) -> None:
    """A header member without the .npy name came back as bytes from np.load (AttributeError)."""
    members = members_of(files["btel-c"])
    plain = [(HEADER_KEY, storage_header_bytes(files["btel-c"]))] + members[1:]
    (tmp_path / "a.npz").write_bytes(zip_of(plain))
    with pytest.raises(ModelFileError, match="not a btel model"):
        btel.load(tmp_path / "a.npz")
    (tmp_path / "b.npz").write_bytes(zip_of(members + [("notes.txt", b"hello")]))
    with pytest.raises(ModelFileError, match="'notes.txt', which is not an array"):
        btel.load(tmp_path / "b.npz")
    (tmp_path / "c.npz").write_bytes(zip_of(members + [members[1]]))
    with pytest.raises(ModelFileError, match="twice"):
        btel.load(tmp_path / "c.npz")


def storage_header_bytes(path: Path) -> bytes:
    _, header = load_arrays(path)
    return json.dumps(header).encode()


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (lambda t: t.replace('"fit_time": ', '"fit_time": 1e400, "x": '), "out of range"),  # OverflowError
        (lambda t: t.replace('"C": null', '"C": NaN'), "NaN is not a number"),
        (lambda t: t.replace('"fit_time": ', '"fit_time": [NaN], "x": '), "NaN is not a number"),
        (lambda t: t.replace('"fit_time": ', '"fit_time": -Infinity, "x": '), "Infinity is not a number"),
        (lambda t: t.replace('"fit_time": ', '"fit_time": ' + "9" * 5000 + ', "x": '), "5000 digits"),
        (lambda t: t.replace('"fit_time": ', '"fit_time": 1' + "0" * 30 + ', "x": '), "31 digits"),
        (lambda t: t.replace('"fit_time": ', '"fit_time": ' + "[" * 100_000 + "]" * 100_000 + ', "x": '),
         "nested"),  # RecursionError
        (lambda t: t.replace('"fit_time": ', '"fit_time": ' + "[" * 40 + "]" * 40 + ', "x": '), "nested"),
        (lambda t: t.replace('"model": "BTELocalizer"', '"model": ["BTELocalizer"]'), "unknown type"),  # unhashable
        (lambda t: t.replace('"model": "BTELocalizer"', '"model": {"a": 1}'), "unknown type"),
        (lambda t: t.replace('"format_version": 1', '"format_version": true'), "no valid format version"),
        (lambda t: t.replace('"format_version": 1', '"format_version": 0'), "invalid format version"),
        (lambda t: t[: len(t) // 2], "corrupt header"),
    ],
)
def test_header_json_is_parsed_strictly(edit, message, files, tmp_path) -> None:
    with pytest.raises(ModelFileError, match=message):
        btel.load(rewrite(files["btel-c"], tmp_path / "m.npz", header_text=edit))


@pytest.mark.parametrize(("path", "error"), [(3, InvalidParameterError), ("a\0b.npz", ModelFileError),
                                             ("x" * 5000 + ".npz", ModelFileError)])
def test_paths_that_cannot_name_a_model_file(path, error) -> None:
    with pytest.raises(error):
        btel.load(path)


def test_a_nan_fit_time_from_an_earlier_btel_still_loads(files, queries, tmp_path) -> None:
    """Earlier btel wrote a loaded model's unknown fit time as NaN when it was saved again."""
    edit = lambda t: t.replace('"fit_time": ', '"fit_time": NaN, "fit_time_was": ')  # noqa: E731
    model = btel.load(rewrite(files["btel-c"], tmp_path / "m.npz", header_text=edit))
    assert np.isnan(model.fit_time_)
    again = btel.load(model.save(tmp_path / "again.npz"))  # saved as null now
    assert np.isnan(again.fit_time_) and '"fit_time": null' in json.dumps(load_arrays(tmp_path / "again.npz")[1])
    np.testing.assert_array_equal(again.predict(queries), model.predict(queries))


def test_a_header_that_is_not_bytes(files, tmp_path) -> None:
    text = json.dumps(load_arrays(files["btel-c"])[1])
    members = members_of(files["btel-c"])
    members[0] = (HEADER_KEY + ".npy", npy(np.array([text])))  # a unicode array
    (tmp_path / "m.npz").write_bytes(zip_of(members))
    with pytest.raises(ModelFileError, match="'__btel_header__' has dtype <U"):
        btel.load(tmp_path / "m.npz")


def test_an_encrypted_member_is_a_model_file_error(files, tmp_path) -> None:
    """zipfile raised RuntimeError ("password required")."""
    data = bytearray(files["btel-c"].read_bytes())
    for marker, flag_offset in ((b"PK\x03\x04", 6), (b"PK\x01\x02", 8)):
        start = data.find(marker, 100)  # a member after the header
        data[start + flag_offset] |= 1
    (tmp_path / "m.npz").write_bytes(bytes(data))
    with pytest.raises(ModelFileError, match="encrypted"):
        btel.load(tmp_path / "m.npz")


@pytest.mark.parametrize("method", [zipfile.ZIP_DEFLATED, zipfile.ZIP_BZIP2, zipfile.ZIP_LZMA])
def test_compressed_members_are_refused(method, files, tmp_path) -> None:
    members = members_of(files["btel-c"])
    (tmp_path / "m.npz").write_bytes(zip_of(members, {members[2][0]: method}))
    with pytest.raises(ModelFileError, match="compressed"):
        btel.load(tmp_path / "m.npz")


def test_cli_reports_a_damaged_descriptor_archive_in_one_line(tmp_path) -> None:
    """`btel train db.npz` printed a BadZipFile traceback."""
    np.savez(tmp_path / "db.npz", X=np.random.default_rng(0).standard_normal((40, 8)).astype(np.float32))
    data = bytearray((tmp_path / "db.npz").read_bytes())
    data[len(data) // 2] ^= 0xFF  # inside the array's bytes: a bad CRC
    (tmp_path / "db.npz").write_bytes(bytes(data))
    result = CliRunner().invoke(main, ["train", str(tmp_path / "db.npz"), "-o", str(tmp_path / "m.npz")])
    assert result.exit_code == 2
    assert result.stderr.startswith("Error: ") and "damaged .npz archive" in result.stderr
    assert len(result.stderr.strip().splitlines()) == 1 and result.exception is None or \
        isinstance(result.exception, SystemExit)


def test_cli_reports_a_bad_model_file_in_one_line(files, queries, tmp_path) -> None:
    np.save(tmp_path / "q.npy", queries)
    path = rewrite(files["btel-c"], tmp_path / "m.npz", header_text=lambda t: t.replace('"fit_time": ', '"fit_time": ' + "[" * 100_000 + "]" * 100_000 + ', "x": '))
    result = CliRunner().invoke(main, ["localize", str(path), str(tmp_path / "q.npy"), "-o", str(tmp_path / "p.csv")])
    assert result.exit_code == 2 and len(result.stderr.strip().splitlines()) == 1
    assert result.stderr.startswith("Error: ") and "nested too deeply" in result.stderr


# ============================================================================= 4. decompression bombs
def test_a_decompression_bomb_is_refused_before_it_is_inflated(files, tmp_path, monkeypatch) -> None:
    """1.9 MB deflated took 2.0 GB and 12 s before rejection: now no compressed member is ever opened."""
    header = "{'descr': '<f4', 'fortran_order': False, 'shape': (50000000,), }"
    members = members_of(files["btel-c"]) + [("bomb.npy", raw_npy(header, bytes(200_000_000)))]
    path = tmp_path / "bomb.npz"
    path.write_bytes(zip_of(members, {"bomb.npy": zipfile.ZIP_DEFLATED}))
    assert path.stat().st_size < 1_000_000
    opened = []
    real_open = zipfile.ZipFile.open
    monkeypatch.setattr(zipfile.ZipFile, "open",
                        lambda self, name, *a, **k: opened.append(getattr(name, "filename", name))
                        or real_open(self, name, *a, **k))
    with pytest.raises(ModelFileError, match="compressed"):
        btel.load(path)
    assert opened == []


def test_declared_sizes_beyond_the_file_are_refused(files, tmp_path) -> None:
    data = bytearray(files["btel-c"].read_bytes())
    central = data.find(b"PK\x01\x02")
    data[central + 20 : central + 28] = struct.pack("<II", 2**31, 2**31)  # compressed, uncompressed size
    (tmp_path / "m.npz").write_bytes(bytes(data))
    with pytest.raises(ModelFileError, match="declares 2147483648 B in a file of"):
        btel.load(tmp_path / "m.npz")


# ============================================================================= 5. saves
def test_concurrent_saves_to_one_path_never_corrupt_it(route, tmp_path) -> None:
    """Both saves wrote `path + ".part"`: 5 of 10 concurrent pairs corrupted the file."""
    a = make_method("bruteforce").fit(route.map)
    b = make_method("bruteforce").fit(route.map[::-1].copy())
    path = tmp_path / "m.npz"
    errors: list[BaseException] = []

    def save(model, barrier) -> None:
        try:
            barrier.wait()
            for _ in range(5):
                model.save(path)
        except BaseException as exc:  # noqa: BLE001 (reported below)
            errors.append(exc)

    for _ in range(10):
        barrier = threading.Barrier(2)
        threads = [threading.Thread(target=save, args=(m, barrier)) for m in (a, b)]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        assert errors == []
        loaded = btel.load(path)
        assert np.array_equal(loaded.descriptors_, a.descriptors_) or np.array_equal(loaded.descriptors_,
                                                                                     b.descriptors_)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["m.npz"]


@pytest.mark.parametrize("interruption", [KeyboardInterrupt, OSError])
def test_a_failed_save_leaves_the_old_file_and_no_temporary(interruption, route, tmp_path, monkeypatch) -> None:
    """Killed saves left 40–410 MB `.part` files."""
    model = make_method("bruteforce").fit(route.map)
    path = model.save(tmp_path / "m.npz")
    before = path.read_bytes()

    def broken_savez(fh, **arrays) -> None:
        fh.write(b"PK\x03\x04 half a model")
        raise interruption("interrupted")

    monkeypatch.setattr(modelfile.np, "savez", broken_savez)
    with pytest.raises(KeyboardInterrupt if interruption is KeyboardInterrupt else ModelFileError):
        model.save(path)
    assert path.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["m.npz"]


def test_saved_files_are_readable_like_any_new_file(route, tmp_path) -> None:
    import os

    path = make_method("bruteforce").fit(route.map).save(tmp_path / "m.npz")
    mask = os.umask(0o022)
    os.umask(mask)
    assert path.stat().st_mode & 0o777 == 0o666 & ~mask


@pytest.mark.parametrize("where", ["folder", "under-a-file", "empty"])
def test_save_to_a_path_that_cannot_be_a_file(where, route, tmp_path) -> None:
    model = make_method("bruteforce").fit(route.map)
    (tmp_path / "plain").write_text("x")
    target = {"folder": tmp_path, "under-a-file": tmp_path / "plain" / "m.npz", "empty": ""}[where]
    message = {"folder": "is a folder", "under-a-file": "is a file, not a folder", "empty": "path is empty"}[where]
    with pytest.raises(InvalidParameterError, match=message):
        model.save(target)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["plain"]  # no "<dir>.part"


def test_save_to_something_that_is_not_a_path(route) -> None:
    with pytest.raises(InvalidParameterError, match="must be a string or a path"):
        make_method("bruteforce").fit(route.map).save(3)


# ============================================================================= 6. streaming bytes
@pytest.mark.parametrize("source", ["stdin", "file"])
def test_stream_treats_a_line_that_is_not_utf8_as_one_malformed_line(source, files, queries, tmp_path) -> None:
    """`'utf-8' codec can't decode byte 0xff` ended the stream with exit 1."""
    model = btel.load(files["btel-c"])
    good = [",".join(repr(v) for v in row.tolist()).encode() + b"\n" for row in queries[:4]]
    feed = good[0] + b"\xff\xfe1,2\n" + good[1] + b"0.5,\xe9\n" + good[2] + good[3]
    args = ["localize", str(files["btel-c"]), "--stream"]
    if source == "file":
        (tmp_path / "frames.txt").write_bytes(feed)
        result = CliRunner().invoke(main, args + ["--input", str(tmp_path / "frames.txt")])
    else:
        result = CliRunner().invoke(main, args, input=feed)
    assert result.exit_code == 1, result.stderr  # a line skipped: exit 1 (not every input answered)
    assert [int(v) for v in result.stdout.split()] == model.predict(queries[:4]).tolist()
    errors = result.stderr.strip().splitlines()
    assert errors[0] == "error: line 2: not UTF-8 text (byte 0xff at column 1). (skipped)"
    assert errors[1].startswith("error: line 4: not UTF-8 text (byte 0xe9 at column 5)")
    assert errors[2] == "4 predictions; 2 malformed line(s) skipped"


def test_localize_stream_reads_bytes_line_by_line(files, queries) -> None:
    from btel.sequence.streaming import localize_stream

    model = btel.load(files["btel-c"])
    lines = b"".join(",".join(repr(v) for v in row.tolist()).encode() + b"\n" for row in queries[:3])
    reported = []
    out = list(localize_stream(model, io.BytesIO(b"\x80\n" + lines), on_error=lambda n, m: reported.append(n)))
    assert [place for _, place in out] == model.predict(queries[:3]).tolist()
    assert reported == [1]


# ============================================================================= 7. never −1
@pytest.mark.parametrize("name", ["bruteforce", "pq", "opq", "itq", "seqslam"])
def test_queries_too_large_for_float32_distances_are_refused(name, route) -> None:
    """Finite queries ≥ 1e19 came back as place −1 from faiss."""
    model = make_method(name, normalize="none").fit(route.map)
    Q = route.queries[:4].copy()
    Q[2] = 1e19
    with pytest.raises(InvalidDescriptorsError, match="Q row 2 has length"):
        model.predict(Q)
    with pytest.raises(InvalidDescriptorsError, match="Q row 0 has length"):
        model.stream().search(Q[2])
    assert model.predict(Q[:2]).min() >= 0  # ordinary queries still answer


@pytest.mark.parametrize("name", ["bruteforce", "pq"])
def test_a_map_too_large_for_float32_distances_is_refused(name, route) -> None:
    X = route.map.copy()
    X[5] *= np.float32(1e20)
    with pytest.raises(InvalidDescriptorsError, match="X row 5 has length"):
        make_method(name, normalize="none").fit(X)


@pytest.mark.parametrize("name", ["bruteforce", "pq", "opq"])
def test_an_index_without_finite_distances_never_answers_minus_one(name, route) -> None:
    """NaN codebooks (or any overflow) made faiss answer −1: refused instead, naming the query."""
    model = make_method(name).fit(route.map)
    index = model.pq_._index if name == "opq" else model._index
    real_search = index.search

    def search(Q, k):
        dist, rows = real_search(Q, k)
        rows[1] = -1
        return dist, rows

    if name == "opq":
        model.pq_._index = type("Index", (), {"search": staticmethod(search)})()
    else:
        model._index = type("Index", (), {"search": staticmethod(search)})()
    with pytest.raises(InvalidDescriptorsError, match="query row 1 has no finite distance"):
        model.predict(route.queries[:3])


# ============================================================================= 8. API parameters
def test_ryth_before_fit_is_not_fitted(route) -> None:
    for call in (lambda m: m.predict(route.queries), lambda m: m.rank(route.queries, 3),
                 lambda m: m.place_scores(route.queries), lambda m: m.predict_sequence(route.queries)):
        with pytest.raises(NotFittedError):
            call(make_method("ryth"))


@pytest.mark.parametrize("n_places", [2, 3])
def test_ryth_on_too_few_places(n_places, route) -> None:
    with pytest.raises(NotEnoughPlacesError, match="needs N ≥"):
        make_method("ryth").fit(route.map[:n_places])


@pytest.mark.parametrize(
    ("name", "param", "value"),
    [
        ("btel-c", "random_state", -1), ("btel-c", "random_state", 2**32), ("btel-c", "random_state", "seed"),
        ("pq", "random_state", 2**31), ("itq", "random_state", 2**31),  # OverflowError in faiss' C int seed
        ("ryth", "random_state", 1.5), ("pq", "random_state", -5), ("itq", "random_state", [0]),
        ("btel-c", "C", float("inf")), ("ryth", "C", float("nan")), pytest.param("btel-c", "C", 10**400, id="btel-c-C-10**400"),
        ("btel-c", "kts_pca_dims", 0), ("btel-c", "kts_pca_dims", -3),
        ("btel-c", "n_jobs", 0), ("ryth", "n_jobs", 0), ("pq", "n_jobs", 0), ("bruteforce", "n_jobs", -2),
        pytest.param("btel-c", "max_iter", 10**30, id="btel-c-max_iter-10**30"), ("ryth", "max_iter", 2**31),
        pytest.param("btel-c", "n_features", 10**400, id="btel-c-n_features-10**400"), ("seqslam", "vskip", 1e-300),
    ],
)
def test_api_parameters_are_named_errors(name, param, value, route) -> None:
    with pytest.raises(InvalidParameterError, match=param):
        make_method(name).set_params(**{param: value}).fit(route.map)


def test_places_with_a_huge_label_are_refused_before_counting(route) -> None:
    """A label of 10¹² asked for a 7 TiB count table."""
    places = np.arange(N_PLACES)
    places[-1] = 10**12
    with pytest.raises(InvalidParameterError, match="missing"):
        make_method("bruteforce").fit(route.map, places)
    with pytest.raises(InvalidParameterError, match="places must"):
        make_method("bruteforce").fit(route.map, places.astype(np.float64) * 1e10)


def test_unknown_hmm_options_are_named(files, queries) -> None:
    model = btel.load(files["btel-c"])
    with pytest.raises(InvalidParameterError, match="decoder='hmm' takes"):
        model.predict_sequence(queries, "hmm", velocity=3)
    with pytest.raises(InvalidParameterError, match="takes only window"):
        model.predict_sequence(queries, "median", vmax=3)


@pytest.mark.parametrize(
    ("predictions", "n_places", "message"),
    [
        ([1, 2, np.nan, 3], None, "no NaN"),
        ([1.0, 2.5], None, "no NaN or fractions"),
        ([1, 2, 64], 64, "below N = 64"),
        ([1, -1, 2], None, "≥ 0"),
        (["a", "b"], None, "dtype"),
        ([1e300], None, "beyond"),
        ([2**64 - 1], None, "beyond"),
    ],
)
def test_filter_sequence_refuses_what_is_not_a_place(predictions, n_places, message) -> None:
    with pytest.raises(InvalidParameterError, match=message):
        btel.filter_sequence(np.asarray(predictions), 2, n_places=n_places)


def test_filter_sequence_window_and_update_checks() -> None:
    from btel.sequence.filter import SequenceFilter

    with pytest.raises(InvalidParameterError, match="window must be at most"):
        SequenceFilter(10**19)
    f = SequenceFilter(2, n_places=10)
    with pytest.raises(InvalidParameterError, match="below N = 10"):
        f.update(10)
    with pytest.raises(InvalidParameterError, match="no NaN"):
        f.update(float("nan"))
    assert f.update(np.int64(3)) == 3


# ============================================================================= 9. HMM in blocks
def test_hmm_decoding_holds_one_block_of_scores_at_a_time(files, route, monkeypatch) -> None:
    """`btel localize --hmm` held the whole (queries × N) score matrix (10 GB at 200k × 2000)."""
    import btel.methods.base
    from btel.sequence.hmm import decode_sequence, emission_scores

    model = btel.load(files["btel-c"])
    Q = np.concatenate([route.queries] * 3)
    expected = decode_sequence(emission_scores(model, Q))
    monkeypatch.setattr(btel.methods.base, "_SCORE_BLOCK_VALUES", 5 * N_PLACES)  # 5 queries per block
    rows_scored: list[int] = []
    real = type(model)._place_scores
    monkeypatch.setattr(type(model), "_place_scores",
                        lambda self, Qt: rows_scored.append(Qt.shape[0]) or real(self, Qt))
    np.testing.assert_array_equal(model.predict_sequence(Q, "hmm"), expected)
    assert max(rows_scored) == 5 and sum(rows_scored) == Q.shape[0]


def test_cli_localize_hmm_decodes_in_blocks(files, route, tmp_path, monkeypatch) -> None:
    import btel.methods.base

    np.save(tmp_path / "q.npy", route.queries)
    expected = btel.load(files["btel-c"]).predict_sequence(route.queries, "hmm")
    monkeypatch.setattr(btel.methods.base, "_SCORE_BLOCK_VALUES", 4 * N_PLACES)
    rows_scored: list[int] = []
    real = btel.BTELocalizer._place_scores
    monkeypatch.setattr(btel.BTELocalizer, "_place_scores",
                        lambda self, Qt: rows_scored.append(Qt.shape[0]) or real(self, Qt))
    result = CliRunner().invoke(main, ["localize", str(files["btel-c"]), str(tmp_path / "q.npy"), "-o",
                                       str(tmp_path / "p.csv"), "--hmm"])
    assert result.exit_code == 0, result.stderr
    got = np.loadtxt(tmp_path / "p.csv", delimiter=",", skiprows=1, dtype=np.int64)[:, 1]
    np.testing.assert_array_equal(got, expected)
    assert max(rows_scored) == 4


def test_every_error_here_is_a_btel_error() -> None:
    # What the tests above expect to be raised is the project's own error (and a ModelFileError is an OSError).
    assert issubclass(ModelFileError, BTELError) and issubclass(ModelFileError, OSError)
