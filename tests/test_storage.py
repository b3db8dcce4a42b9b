"""Budgets, storage accounting and model files: round trips and every kind of bad file (SPEC §7)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import btel
from btel import BTELocalizer
from btel.datasets import synthetic_route
from btel.exceptions import (
    InvalidParameterError,
    ModelFileError,
    NotFittedError,
    UnsupportedModelVersionError,
)
from btel.core.storage import format_bytes, parse_budget, storage_breakdown
from btel.core.modelfile import FORMAT_VERSION, HEADER_KEY, load_arrays, save_arrays

MAX_OVERHEAD = 4096  # file size − reported bytes (SPEC §7: "a few KiB")


@pytest.fixture(scope="module")
def route():
    return synthetic_route(160, 48, n_traverses=2, n_regions=4, seed=11)


@pytest.fixture(scope="module")
def model_file(route, tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("model") / "model.npz"
    BTELocalizer(n_regions=3, progress=False, random_state=0).fit(route.map).save(path)
    return path


# ----------------------------------------------------------------------------- budgets
@pytest.mark.parametrize(
    ("budget", "expected"),
    [
        (None, None),
        (500, 500),
        (np.int64(7), 7),
        (1e3, 1000),
        ("500KB", 500_000),
        ("500kb", 500_000),
        ("2 MB", 2_000_000),
        (" 1.5mb ", 1_500_000),
        ("64KiB", 65_536),
        ("1MiB", 1_048_576),
        ("2GiB", 2 * 1024**3),
        ("1GB", 10**9),
        ("100B", 100),
        ("100", 100),
        ("1e3", 1000),
        (".5KB", 500),
    ],
)
def test_parse_budget(budget, expected) -> None:
    assert parse_budget(budget) == expected


@pytest.mark.parametrize("budget", ["", "abc", "10 XB", "KB", "1.2.3MB", "5 K B", "0x10", "1,000"])
def test_parse_budget_rejects_malformed_strings(budget: str) -> None:
    with pytest.raises(InvalidParameterError, match="is not understood; write bytes or a size such as '500KB'"):
        parse_budget(budget)


@pytest.mark.parametrize("budget", ["-5KB", "0", "0KB", "-1e3"])
def test_parse_budget_names_a_budget_that_is_not_positive(budget: str) -> None:
    with pytest.raises(InvalidParameterError, match="must be a positive number of bytes"):
        parse_budget(budget)


@pytest.mark.parametrize(("budget", "bytes_spelling"), [("10Kb", "'10KB'"), ("2Mb", "'2MB'"), ("64Kib", "'64KiB'")])
def test_parse_budget_refuses_the_spelling_of_bits(budget: str, bytes_spelling: str) -> None:
    # A capital prefix with a small b is how bits are written: read as bytes it would be 8x too large.
    with pytest.raises(InvalidParameterError, match=f"reads as bits.*{bytes_spelling} for bytes"):
        parse_budget(budget)


@pytest.mark.parametrize("budget", [0, -1, 0.0, float("nan"), "0KB"])
def test_parse_budget_rejects_non_positive_budgets(budget) -> None:
    with pytest.raises(InvalidParameterError, match="budget must be a positive number of bytes"):
        parse_budget(budget)


@pytest.mark.parametrize("budget", [float("inf"), 10 ** 400, 10 ** 30, np.uint64(2 ** 63 + 5), "1e300", "1e400KB"])
def test_parse_budget_refuses_more_bytes_than_any_model_stores(budget) -> None:
    """10**400 raised OverflowError; 10**30 gave a model that saved and then failed to load ("corrupt header: an
    integer of 31 digits"); np.uint64(2**63 + 5) was rounded through float."""
    with pytest.raises(InvalidParameterError, match="more bytes than any model stores"):
        parse_budget(budget)
    assert parse_budget(2 ** 62) == 2 ** 62 and parse_budget(np.uint64(2 ** 62 - 3)) == 2 ** 62 - 3


@pytest.mark.parametrize("budget", [True, [500], {"b": 1}, b"500KB"])
def test_parse_budget_rejects_other_types(budget) -> None:
    with pytest.raises(InvalidParameterError, match="budget must be a number of bytes or a string"):
        parse_budget(budget)


def test_malformed_budget_is_reported_by_fit() -> None:
    X = np.random.default_rng(0).standard_normal((10, 4))
    with pytest.raises(InvalidParameterError, match="budget '12 parsecs' is not understood"):
        BTELocalizer(budget="12 parsecs", progress=False).fit(X)


@pytest.mark.parametrize(
    ("n", "text"), [(0, "0 B"), (999, "999 B"), (1000, "1.0 KB"), (492_240, "492.2 KB"), (2e6, "2.0 MB"), (3e9, "3.0 GB")]
)
def test_format_bytes(n, text: str) -> None:
    assert format_bytes(n) == text


def test_storage_breakdown_counts_array_bytes_at_their_dtype() -> None:
    arrays = {"w": np.zeros((3, 4), np.float16), "b": np.zeros(3, np.float32), "c": np.zeros((3, 4), np.uint16)}
    assert storage_breakdown(arrays) == {"w": 24, "b": 12, "c": 24}


# ----------------------------------------------------------------------------- model round trips
CONFIGS = {
    "compressed": {},
    "compressed-all-columns": {"feature_ratio": 1.0},
    "full": {"scheme": "full"},
    "regions-2": {"n_regions": 2},
    "regions-5": {"n_regions": 5},
    "regions-auto": {"n_regions": "auto"},
    "float16": {"dtype": "float16"},
    "float16-as-type": {"dtype": np.float16},
    "soft-decode": {"decode": "soft"},
    "logistic": {"classifier": "logistic"},
    "budget": {"budget": "3KB", "n_regions": 3},
    "full-regions-float16": {"scheme": "full", "n_regions": 3, "dtype": "float16"},
}


def assert_same_model(model: BTELocalizer, loaded: BTELocalizer, Q: np.ndarray) -> None:
    assert type(loaded) is BTELocalizer
    np.testing.assert_array_equal(loaded.predict(Q), model.predict(Q))
    np.testing.assert_array_equal(loaded.decision_function(Q), model.decision_function(Q))  # NaN == NaN here
    np.testing.assert_array_equal(loaded.predict_region(Q), model.predict_region(Q))
    assert loaded.storage_breakdown() == model.storage_breakdown()
    assert loaded.nbytes == model.nbytes
    assert (loaded.n_places_, loaded.n_features_in_, loaded.n_selected_, loaded.n_regions_) == (
        model.n_places_, model.n_features_in_, model.n_selected_, model.n_regions_)
    np.testing.assert_array_equal(loaded.region_starts_, model.region_starts_)
    assert loaded.hyperplanes_.weights.dtype == model.hyperplanes_.weights.dtype


@pytest.mark.parametrize("params", list(CONFIGS.values()), ids=list(CONFIGS))
def test_save_load_gives_identical_predictions(params, route, tmp_path: Path) -> None:
    model = BTELocalizer(progress=False, random_state=0, **params).fit(route.map)
    path = model.save(tmp_path / "sub" / "model.npz")  # the folder is created
    assert path.exists() and not path.with_name(path.name + ".part").exists()
    loaded = btel.load(path)
    assert_same_model(model, loaded, route.queries)
    assert 0 <= path.stat().st_size - model.nbytes <= MAX_OVERHEAD
    # Parameters survive (dtype given as a numpy type is stored by name); runtime settings (n_jobs,
    # backend, scheduler, progress) are not model content and come back at their defaults.
    defaults = BTELocalizer().get_params()
    expected = {k: (np.dtype(v).name if k == "dtype" else defaults[k] if k in BTELocalizer._runtime_params else v)
                for k, v in model.get_params().items()}
    assert loaded.get_params() == expected
    # The file holds exactly the stored arrays, nothing else.
    arrays, header = load_arrays(path)
    assert set(arrays) == set(model.storage_breakdown())
    assert "n_jobs" not in header["params"] and "progress" not in header["params"]
    assert header["model"] == "BTELocalizer" and header["format_version"] == FORMAT_VERSION


@settings(max_examples=15, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    n=st.integers(6, 120),  # r = 3 needs 6 places
    d=st.integers(2, 40),
    scheme=st.sampled_from(["compressed", "full"]),
    dtype=st.sampled_from(["float32", "float16"]),
    n_regions=st.sampled_from([1, 2, 3, "auto"]),
    soft=st.booleans(),
    feature_ratio=st.sampled_from([None, 0.5, 1.0]),
    seed=st.integers(0, 1000),
)
def test_save_load_round_trip_property(tmp_path: Path, n, d, scheme, dtype, n_regions, soft, feature_ratio, seed) -> None:
    r = synthetic_route(n, d, n_traverses=2, n_regions=3, seed=seed)
    decode = "soft" if soft and scheme == "compressed" else "constrained"
    model = BTELocalizer(scheme=scheme, dtype=dtype, n_regions=n_regions, decode=decode, feature_ratio=feature_ratio,
                         max_regions=8, progress=False, random_state=0).fit(r.map)
    path = model.save(tmp_path / f"model-{seed}-{n}-{d}.npz")
    assert_same_model(model, btel.load(path), r.queries)
    assert path.stat().st_size - model.nbytes <= MAX_OVERHEAD


def test_save_before_fit() -> None:
    with pytest.raises(NotFittedError, match="not fitted yet"):
        BTELocalizer().save("never.npz")


# ----------------------------------------------------------------------------- save_arrays / load_arrays
def test_save_arrays_load_arrays_round_trip(tmp_path: Path) -> None:
    arrays = {"a": np.arange(6, dtype=np.uint16).reshape(2, 3), "b": np.array([1.5], np.float16)}
    save_arrays(tmp_path / "x.npz", arrays, {"model": "Nothing", "note": "ü"})
    loaded, header = load_arrays(tmp_path / "x.npz")
    assert set(loaded) == {"a", "b"}
    for k in arrays:
        np.testing.assert_array_equal(loaded[k], arrays[k])
        assert loaded[k].dtype == arrays[k].dtype
    assert header["note"] == "ü" and header["format"] == "btel-model"


def test_save_arrays_refuses_the_header_name_and_object_arrays(tmp_path: Path) -> None:
    with pytest.raises(InvalidParameterError, match="reserved for the model header"):
        save_arrays(tmp_path / "x.npz", {HEADER_KEY: np.zeros(1)}, {})
    with pytest.raises(InvalidParameterError, match="has dtype object"):
        save_arrays(tmp_path / "x.npz", {"o": np.array([{"k": 1}], dtype=object)}, {})
    assert not (tmp_path / "x.npz").exists()


# ----------------------------------------------------------------------------- bad files
def _rewrite(src: Path, dst: Path, *, header_edit=None, arrays_edit=None) -> Path:
    """Copy a model file with its header JSON and/or arrays edited, written with numpy itself."""
    arrays, header = load_arrays(src)
    if header_edit:
        header_edit(header)
    if arrays_edit:
        arrays_edit(arrays)
    raw = np.frombuffer(json.dumps(header).encode("utf-8"), dtype=np.uint8)
    np.savez(dst, **{HEADER_KEY: raw}, **arrays)
    return dst


def test_unedited_rewrite_still_loads(model_file: Path, tmp_path: Path, route) -> None:
    # The helper itself produces loadable files: the failures below come from the edits.
    loaded = btel.load(_rewrite(model_file, tmp_path / "same.npz"))
    np.testing.assert_array_equal(loaded.predict(route.queries), btel.load(model_file).predict(route.queries))


def test_missing_file(tmp_path: Path) -> None:
    with pytest.raises(ModelFileError, match="does not exist"):
        btel.load(tmp_path / "nope.npz")
    # Also an OSError (FileNotFoundError-style handling keeps working).
    with pytest.raises(OSError):
        btel.load(tmp_path / "nope.npz")


def test_folder_instead_of_file(tmp_path: Path) -> None:
    with pytest.raises(ModelFileError, match="is a folder"):
        btel.load(tmp_path)


def test_truncated_file(model_file: Path, tmp_path: Path) -> None:
    data = model_file.read_bytes()
    path = tmp_path / "half.npz"
    path.write_bytes(data[: len(data) // 2])
    with pytest.raises(ModelFileError, match="truncated, corrupt or not a btel model file"):
        btel.load(path)


def _write_npy(path: Path) -> None:
    with open(path, "wb") as fh:  # keep the .npz name: the content decides, not the suffix
        np.save(fh, np.zeros((3, 4)))


def _write_pickle(path: Path) -> None:
    import pickle

    path.write_bytes(pickle.dumps({"weights": [1.0, 2.0]}))


@pytest.mark.parametrize(
    "write",
    [
        pytest.param(lambda p: p.write_bytes(np.random.default_rng(0).integers(0, 256, 5000, np.uint8).tobytes()),
                     id="random-bytes"),
        pytest.param(lambda p: p.write_text("this is not a model\n"), id="plain-text"),
        pytest.param(lambda p: p.write_bytes(b""), id="empty"),
        pytest.param(_write_npy, id="npy-array"),
        pytest.param(_write_pickle, id="pickle"),
    ],
)
def test_files_that_are_not_npz_archives(tmp_path: Path, write) -> None:
    path = tmp_path / "model.npz"
    write(path)
    with pytest.raises(ModelFileError, match=r"is corrupt or not a btel model file \(not an .npz archive\)"):
        btel.load(path)


def test_npz_without_header(tmp_path: Path) -> None:
    path = tmp_path / "descriptors.npz"
    np.savez(path, X=np.zeros((3, 4)))
    with pytest.raises(ModelFileError, match="is an .npz file but not a btel model"):
        btel.load(path)


def test_npz_with_pickled_objects(model_file: Path, tmp_path: Path) -> None:
    # Foreign .npz holding an object array (a pickle) — never unpickled.
    foreign = tmp_path / "pickle.npz"
    np.savez(foreign, payload=np.array([{"run": "code"}], dtype=object))
    with pytest.raises(ModelFileError, match="not a btel model"):
        btel.load(foreign)
    # Same, disguised with a genuine btel header: refused when the arrays are read.
    disguised = _rewrite(model_file, tmp_path / "disguised.npz",
                         arrays_edit=lambda a: a.update(payload=np.array([{"run": "code"}], dtype=object)))
    with pytest.raises(ModelFileError, match="contains pickled objects; btel never loads pickles"):
        btel.load(disguised)


def test_newer_format_version(model_file: Path, tmp_path: Path) -> None:
    path = _rewrite(model_file, tmp_path / "future.npz",
                    header_edit=lambda h: h.update(format_version=FORMAT_VERSION + 1))
    with pytest.raises(UnsupportedModelVersionError, match=f"format version {FORMAT_VERSION + 1}, newer than this btel"):
        btel.load(path)


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (lambda h: h.update(format="something-else"), "foreign header"),
        (lambda h: h.pop("format_version"), "no valid format version"),
        (lambda h: h.update(format_version="1"), "no valid format version"),
        (lambda h: h.update(model="NotAModel"), "unknown type 'NotAModel'"),
        (lambda h: h.update(params=[1, 2]), "params/state are not objects"),
        (lambda h: h.update(params={"bogus": 1}), "parameters \\['bogus'\\] that BTELocalizer does not take"),
        (lambda h: h["state"].update(n_places=1), r"n_places = 1 is not an integer in \[2, "),
        (lambda h: h["state"].update(n_places=10_000), "classifiers; its regions imply"),
        (lambda h: h["state"].update(n_selected=0), "n_selected = 0 is not an integer in"),
        (lambda h: h["state"].pop("n_features_in"), "n_features_in = None is not an integer"),
    ],
)
def test_edited_headers(model_file: Path, tmp_path: Path, edit, message: str) -> None:
    path = _rewrite(model_file, tmp_path / "edited.npz", header_edit=edit)
    with pytest.raises(ModelFileError, match=message):
        btel.load(path)


def _set(key, value):
    return lambda a: a.__setitem__(key, value(a))


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (lambda a: a.pop("bias"), "lacks the array 'bias'"),
        (lambda a: a.pop("region_weights"), "lacks the array 'region_weights'"),
        (_set("weights", lambda a: a["weights"][:-1]), "classifiers; its regions imply"),
        (_set("columns", lambda a: np.full_like(a["columns"], 60000)), "columns index past d"),
        (lambda a: a.pop("columns"), "lacks the array 'columns'"),
        (_set("region_starts", lambda a: a["region_starts"][::-1].copy()), "region starts are not increasing"),
        (_set("region_weights", lambda a: a["region_weights"][:1]), "array 'region_weights' has shape"),
    ],
)
def test_edited_arrays(model_file: Path, tmp_path: Path, edit, message: str) -> None:
    path = _rewrite(model_file, tmp_path / "edited.npz", arrays_edit=edit)
    with pytest.raises(ModelFileError, match=message):
        btel.load(path)


def test_corrupt_header_bytes(model_file: Path, tmp_path: Path) -> None:
    arrays, _ = load_arrays(model_file)
    path = tmp_path / "badheader.npz"
    np.savez(path, **{HEADER_KEY: np.frombuffer(b"\xff{not json", dtype=np.uint8)}, **arrays)
    with pytest.raises(ModelFileError, match="corrupt header"):
        btel.load(path)


@pytest.mark.parametrize("n, text", [(100, "100 B"), (999, "999 B"), (1000, "1.0 KB (1000 B)"),
                                     (492240, "492.2 KB (492240 B)")])
def test_exact_bytes_adds_the_bytes_only_when_the_rounded_size_is_not_exact(n: int, text: str) -> None:
    from btel.core.storage import exact_bytes

    assert exact_bytes(n) == text


@pytest.mark.parametrize("budget", ["0.5B", 0.5, "1e-300KB", "0.0009KB"])
def test_parse_budget_refuses_less_than_one_byte(budget) -> None:
    """'0.5B' was floored to 0 B and passed the positivity check ("the whitening matrix alone needs 0 B")."""
    with pytest.raises(InvalidParameterError, match="less than one byte"):
        parse_budget(budget)


def test_parse_budget_rounds_a_fraction_of_a_byte_down() -> None:
    assert parse_budget("1.5B") == 1 and parse_budget("0.5KB") == 500 and parse_budget(1.9) == 1
