"""Answers always in [0, N) (issue 20, finding 4): the base class checks every method's scores and
places, and `btel evaluate --model` no longer scores a model that answers −1."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import btel
from btel.base import ArraySpec, PlaceLocalizer
from btel.exceptions import InvalidAnswerError


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


def _overflowing_codes(tmp_path: Path) -> tuple[Path, np.ndarray]:
    rng = np.random.default_rng(0)
    X = rng.normal(size=(120, 16)).astype(np.float32)
    model = btel.make_method("btel-codes").fit(X)
    model.bias_ = np.full_like(model.bias_, np.finfo(np.float32).max)  # finite, so the file loads
    return model.save(tmp_path / "codes.btel"), X


def test_a_codes_model_with_float32_max_bias_is_an_error_not_place_minus_one(tmp_path: Path) -> None:
    path, X = _overflowing_codes(tmp_path)
    model = btel.load(path)
    with pytest.raises(InvalidAnswerError, match="outside the map|non-finite"):
        model.predict(X[:10])


def test_evaluate_reports_it_in_one_line(tmp_path: Path) -> None:
    path, X = _overflowing_codes(tmp_path)
    np.save(tmp_path / "q.npy", X[:20])
    proc = subprocess.run([sys.executable, "-m", "btel.cli", "evaluate", "--model", str(path), "--queries",
                           str(tmp_path / "q.npy"), "--out", str(tmp_path / "run")],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode in (1, 3), proc.stderr
    assert "Traceback" not in proc.stderr
    metrics = (tmp_path / "run" / "metrics.json")
    if metrics.exists():  # a row that failed, with its reason, never status ok with a recall
        text = metrics.read_text()
        assert '"ok"' not in text and ("outside the map" in text or "non-finite" in text)
    else:
        assert "outside the map" in proc.stderr or "non-finite" in proc.stderr
