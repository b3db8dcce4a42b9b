"""Answers always in [0, N) (issue 20, finding 4): the base class checks every method's scores and
places, and `btel evaluate --model` no longer scores a model that answers −1."""

from __future__ import annotations

import functools
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import btel
from btel.methods.base import ArraySpec, PlaceLocalizer
from btel.exceptions import InvalidAnswerError
from btel.methods import METHODS


class _Fixed(PlaceLocalizer):
    """A toy method answering whatever ``answer``/``score`` say (a stand-in for overflowing weights)."""

    def __init__(self, answer: int = 0, score: float = 0.0) -> None:
        self.answer = answer
        self.score = score

    def _fit(self, X, places, n_places, budget, reserved) -> None:
        pass

    def _search(self, Q: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
        places = (np.arange(k)[None, :] + self.answer) * np.ones((Q.shape[0], 1), dtype=np.int64)
        return np.full((Q.shape[0], k), self.score), places.astype(np.int64)

    def _stored_arrays(self) -> dict[str, np.ndarray]:
        return {}

    def _array_specs(self, state) -> dict[str, ArraySpec]:
        return {}

    def _restore(self, arrays, state) -> None:
        pass


@pytest.mark.parametrize(("answer", "score", "message"), [
    (-1, 0.0, "answered place -1"), (5, 0.0, "answered place 5"), (0, np.nan, "non-finite scores"),
    (0, np.inf, "non-finite scores"),
])
def test_base_class_refuses_answers_outside_the_map(answer: int, score: float, message: str) -> None:
    X = np.random.default_rng(0).normal(size=(5, 4)).astype(np.float32)
    model = _Fixed(answer, score).fit(X)
    calls = [lambda: model.search(X, 2)]
    if not np.isfinite(score) or answer:
        calls += [lambda: model.place_scores(X)] if not np.isfinite(score) else []
    if answer:
        calls += [lambda: model.predict(X), lambda: model.rank(X, 1), lambda: model.stream().search(X[0])]
    for call in calls:
        with pytest.raises(InvalidAnswerError, match=message):
            call()
    assert _Fixed(0, 1.0).fit(X).predict(X).tolist() == [0] * 5


def _overflowing_codes(tmp_path: Path) -> tuple[Path, np.ndarray, PlaceLocalizer]:
    rng = np.random.default_rng(0)
    X = rng.normal(size=(120, 16)).astype(np.float32)
    model = btel.make_method("btel-codes").fit(X)
    model.bias_ = np.full_like(model.bias_, np.finfo(np.float32).max)  # finite, but no fit stores it
    return model.save(tmp_path / "codes.btel"), X, model


def test_a_codes_model_with_float32_max_bias_is_an_error_not_place_minus_one(tmp_path: Path) -> None:
    from btel.exceptions import ModelFileError

    path, X, model = _overflowing_codes(tmp_path)
    with pytest.raises(InvalidAnswerError, match="outside the map|non-finite"):
        model.predict(X[:10])  # in memory: the base class refuses the answers
    with pytest.raises(ModelFileError, match="bias of 3.4e"):
        btel.load(path)  # on disk: the loader refuses what no fit writes


def test_evaluate_reports_it_in_one_line(tmp_path: Path) -> None:
    path, X, _ = _overflowing_codes(tmp_path)
    np.save(tmp_path / "q.npy", X[:20])
    proc = subprocess.run([sys.executable, "-m", "btel.cli", "evaluate", "--model", str(path), "--queries",
                           str(tmp_path / "q.npy"), "--out", str(tmp_path / "run")],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2, proc.stderr
    assert "Traceback" not in proc.stderr and len(proc.stderr.strip().splitlines()) == 1, proc.stderr
    assert "bias of 3.4e+38" in proc.stderr and not (tmp_path / "run" / "metrics.json").exists()


# -- every registered method at extreme scales: refused at fit by name, or answering every entry point -----
SCALES = (1e-44, 1e-38, 1e-15, 1e15, 1e30, 3e37)  # the three, and the edges of the float32 ranges
F32_MAX = float(np.finfo(np.float32).max)


def _route() -> tuple[np.ndarray, np.ndarray]:
    from btel.datasets import synthetic_route

    route = synthetic_route(n_places=64, dim=24, seed=3)
    return route.map.astype(np.float32), route.queries.astype(np.float32)


def _scaled(X: np.ndarray, scale: float) -> np.ndarray:
    return (X.astype(np.float64) * scale).astype(np.float32)


def _answers_everywhere(model: PlaceLocalizer, Q: np.ndarray) -> np.ndarray:
    """Every entry point answers valid places and finite scores; returns the predictions."""
    n = int(model.n_places_)
    predicted = model.predict(Q)
    ranked = model.rank(Q, 5)
    scores, places = model.search(Q, 5)
    every = model.place_scores(Q)
    stream = model.stream()
    streamed = [stream.search(q, 3) for q in Q[:12]]
    stream_scores = model.stream().place_scores(Q[0])
    assert predicted.shape == (Q.shape[0],) and ((0 <= predicted) & (predicted < n)).all()
    assert ranked.shape == (Q.shape[0], 5) and np.array_equal(ranked[:, 0], predicted)
    assert np.array_equal(places, ranked) and np.isfinite(scores).all()
    assert every.shape == (Q.shape[0], n) and np.isfinite(every).all()
    assert all(np.isfinite(s).all() and ((0 <= p) & (p < n)).all() for s, p in streamed)
    assert stream_scores.shape == (n,) and np.isfinite(stream_scores).all()
    return predicted


@functools.lru_cache(maxsize=None)
def _unscaled_predictions(method: str, front_end: str) -> np.ndarray:
    X, Q = _route()
    return btel.make_method(method, **({} if front_end == "default" else {"normalize": "none"})).fit(X).predict(Q)


def _recall(predicted: np.ndarray, tolerance: int = 2) -> float:
    """Share of frame-aligned queries answered within ``tolerance`` places of their own."""
    return float((np.abs(predicted - np.arange(predicted.size)) <= tolerance).mean())


def _save_load(model: PlaceLocalizer, tmp_path: Path) -> PlaceLocalizer:
    return btel.load(model.save(tmp_path / "model.btel.npz"))


@pytest.mark.parametrize("front_end", ["default", "none"])
@pytest.mark.parametrize("scale", SCALES)
@pytest.mark.parametrize("method", list(METHODS))
def test_a_model_fitted_on_a_scaled_map_is_refused_or_answers_after_save_and_load(
        method: str, scale: float, front_end: str, tmp_path: Path) -> None:
    """The fit-time guarantee: what ``fit`` accepts at any scale saves, loads and answers every entry point;
    what it cannot answer it refuses with a named error that says how to scale the map, and no numpy
    warning before it. A front end that normalises (every method's default but SeqSLAM's) makes the
    answers those of the unscaled map."""
    import warnings

    from btel.exceptions import InvalidDescriptorsError

    X, Q = _route()
    params = {} if front_end == "default" else {"normalize": "none"}
    model = btel.make_method(method, **params)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("error", RuntimeWarning)  # overflow / invalid value: the error says it instead
            model.fit(_scaled(X, scale))
    except InvalidDescriptorsError as exc:
        assert "scale the descriptors" in str(exc).lower(), exc
        normalising = model.normalize != "none"
        assert not normalising, f"{method} with an L2 front end refused a map scaled by {scale:g}: {exc}"
        return
    loaded = _save_load(model, tmp_path)
    Qs = _scaled(Q, scale)
    predicted = _answers_everywhere(loaded, Qs)
    assert np.array_equal(predicted, model.predict(Qs))
    if scale != 1e-44:  # at 1e-44 float32 keeps a handful of levels per value: another map
        # As good as on the unscaled map (not the same answers: ITQ's fit turns on the last bit of its input).
        unscaled = _unscaled_predictions(method, front_end)
        assert _recall(predicted) >= _recall(unscaled) - 0.1, (method, scale, _recall(predicted),
                                                               _recall(unscaled))


def _float_arrays(path: Path) -> list[str]:
    from btel.core.modelfile import load_arrays

    arrays, _ = load_arrays(path)
    return [name for name, a in arrays.items() if a.dtype.kind == "f" and a.size]


def _with_one_value(path: Path, name: str, value: float, out: Path) -> Path:
    """A copy of the model file with ``arrays[name].flat[0] = value`` (header kept)."""
    from btel.core.modelfile import load_arrays, save_arrays

    arrays, header = load_arrays(path)
    arrays[name] = arrays[name].copy()
    arrays[name].flat[0] = value
    header = {k: v for k, v in header.items() if k not in ("format", "format_version")}
    return save_arrays(out, arrays, header)


@pytest.mark.parametrize("method", list(METHODS))
def test_one_stored_value_at_the_float32_maximum_is_refused_on_load_or_answered(method: str,
                                                                                tmp_path: Path) -> None:
    """Every float array of every method's file, one at a time: a value no fit stores is a ModelFileError on
    load; anything the loader accepts answers every entry point (never predict working and rank failing)."""
    from btel.exceptions import ModelFileError

    X, Q = _route()
    path = btel.make_method(method).fit(X).save(tmp_path / "model.btel.npz")
    names = _float_arrays(path)
    if not names:  # integer codes only (LSH's sign bits): nothing to set
        return
    for name in names:
        edited = _with_one_value(path, name, F32_MAX, tmp_path / f"edited-{name}.btel.npz")
        try:
            model = btel.load(edited)
        except ModelFileError as exc:
            assert "damaged" in str(exc) or "out-of-range" in str(exc) or "overflow" in str(exc), exc
            continue
        _answers_everywhere(model, Q)


@pytest.mark.realdata
@pytest.mark.parametrize("method", ["btel-c", "btel-codes", "bruteforce", "rabitq", "seqslam", "auto"])
def test_gardens_point_scaled_by_1e_minus_38_is_localized_as_well(method: str, gardenspoint_netvlad) -> None:
    """NetVLAD descriptors of Gardens Point times 1e-38 (subnormal float32 values): a normalising front end
    localizes them as well as the descriptors themselves; without one, the method answers as well too
    (SeqSLAM's byte codes) or refuses the map by name."""
    from btel.exceptions import InvalidDescriptorsError

    X, Q = gardenspoint_netvlad
    try:
        scaled = btel.make_method(method).fit(_scaled(X, 1e-38)).predict(_scaled(Q, 1e-38))
    except InvalidDescriptorsError as exc:
        assert btel.make_method(method).normalize == "none" and "scale the descriptors" in str(exc).lower()
        return
    plain = btel.make_method(method).fit(X).predict(Q)
    assert _recall(plain) > 0.1  # Gardens Point day → night: well above chance (0.025 at ±2 of 200)
    assert _recall(scaled) >= _recall(plain) - 0.05, (method, _recall(scaled), _recall(plain))


def test_top_k_keeps_the_lowest_columns_of_a_tie_at_the_kth_score() -> None:
    """argpartition kept an arbitrary k of the columns tied at the k-th score, so LSH's search of a blank query
    ranked [280 281 282] in a batch of 10 and [0 1 2] in a batch of 5, while predict said 0."""
    from btel.core.topk import top_k

    rng = np.random.default_rng(0)
    for _ in range(200):
        scores = rng.integers(0, 3, size=(rng.integers(1, 6), rng.integers(2, 40))).astype(np.float64)
        k = int(rng.integers(1, scores.shape[1] + 1))
        values, columns = top_k(scores, k)
        expected = np.stack([np.lexsort((np.arange(scores.shape[1]), -row))[:k] for row in scores])
        np.testing.assert_array_equal(columns, expected)
        np.testing.assert_array_equal(values, np.take_along_axis(scores, expected, axis=1))


@pytest.mark.parametrize("name", ["lsh", "bruteforce", "pq", "btel-codes"])
def test_search_predict_and_the_stream_agree_on_ties_whatever_the_batch(name: str) -> None:
    """A blank query ties every place; duplicated map rows tie their places. search(Q)[1][:, 0] is predict(Q),
    for any batch size, and the stream ranks as the batch does (it gave tied places in reverse order)."""
    import warnings

    import btel
    from btel.datasets import synthetic_route

    r = synthetic_route(n_places=300, dim=64, seed=2)
    X = r.map.copy()
    X[200] = X[10]
    X[250] = X[10]
    model = btel.make_method(name, budget=None if name == "bruteforce" else "16KB").fit(X)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the blank query's warning
        for n in (5, 10, 40):
            B = np.concatenate([X[[10]], np.zeros((1, 64), np.float32), r.queries[: n - 2]])
            _, places = model.search(B, 3)
            np.testing.assert_array_equal(places[:, 0], model.predict(B))
            stream = model.stream()
            for row, expected in zip(B[:3], places[:3]):
                np.testing.assert_array_equal(stream.search(row, 3)[1], expected)
