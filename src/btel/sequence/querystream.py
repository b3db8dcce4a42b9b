"""One query at a time through a fitted model, keeping what the next answer needs from the frames before it."""

from __future__ import annotations

from typing import Any

import numpy as np

from ..core.rows import warn_blank_rows
from ..core.topk import as_answered
from ..core.validation import check_descriptors
from ..exceptions import InvalidParameterError

__all__ = ["QueryStream"]


class QueryStream:
    """One query at a time through a fitted model (what a robot runs; ``btel localize --stream``).

    Keeps what answering the next frame needs from the frames before it: the front end's delta
    history (the last 2w frames) and a sequence method's context (SeqSLAM's last ds − 1 frames).
    ``search(x)`` on each frame of a traverse gives what ``model.search(Q)`` gives on the whole
    traverse, row by row — places always; scores too, except SeqSLAM's: OpenSeqSLAM's contrast
    enhancement shifts the whole difference matrix by its minimum, so its scores carry an offset that
    depends on the frames scored together (the batch, or the last ds frames). :meth:`reset` starts a
    new traverse (the robot was moved, a new run).
    """

    def __init__(self, model: Any) -> None:  # a fitted btel.methods.base.PlaceLocalizer (below it here)
        self.model = model
        self._front = model.front_end_.stream()
        self._context = model._sequence_context()
        self._past: list[np.ndarray] = []

    def reset(self) -> None:
        self._front.reset()
        self._past = []

    def _rows(self, x: Any) -> np.ndarray:
        q = check_descriptors(np.asarray(x).reshape(1, -1) if np.ndim(x) == 1 else x, name="query",
                              n_features=self.model.n_features_in_)
        if q.shape[0] != 1:
            raise InvalidParameterError(f"a stream takes one descriptor at a time; got {q.shape[0]} rows.")
        warn_blank_rows(q)
        z = self._front.update(q)
        if not self._context:
            return z
        self._past = (self._past + [z[0]])[-(self._context + 1):]
        return np.asarray(self._past, dtype=np.float32)

    def search(self, x: Any, k: int = 1) -> tuple[np.ndarray, np.ndarray]:
        """(scores, places) of the k best places for the next frame, shapes (k,), best first."""
        scores, places = as_answered(*self.model._search(self._rows(x), self.model._check_k(k)))  # as search
        self.model._check_answers(places[-1:], scores[-1:])
        return scores[-1], places[-1]

    def predict(self, x: Any) -> int:
        """The place of the next frame (the best of :meth:`search`), as ``model.predict`` gives it row by row."""
        return int(self.search(x, 1)[1][0])

    def place_scores(self, x: Any) -> np.ndarray:
        """Scores of every place for the next frame, shape (N,), float64."""
        scores = self.model._place_scores(self._rows(x))[-1]
        self.model._check_answers(None, scores)
        return scores
