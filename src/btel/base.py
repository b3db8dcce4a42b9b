"""The one interface every localization method implements (BTEL and each baseline).

A method is a scikit-learn estimator:

- ``__init__`` only stores its keyword arguments; ``budget`` (bytes or ``"500KB"``) is one of them
  for every method, and ``fit`` picks the largest configuration of the method that fits it;
- ``fit(X, places=None)`` learns from map descriptors (row i = place i when ``places`` is None)
  and returns ``self``;
- ``predict(Q)`` returns int64 place indices, one per query row;
- ``rank(Q, k)`` (only where ``supports_ranking``) returns the k best places per query, best first;
- :meth:`storage_breakdown` and :attr:`nbytes` report storage by the one rule in
  :func:`btel.storage.storage_breakdown`: the bytes of the arrays inference reads.

Subclasses implement ``_stored_arrays()`` (name → array, exactly what inference reads) and, to be
saved and loaded, ``_fitted_state()`` (JSON-serialisable scalars learned by fit) and
``_restore(arrays, state)``. Register a class for :func:`btel.load` with :func:`register_model`.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
from sklearn.base import BaseEstimator

from ._validation import check_descriptors, check_is_fitted
from .exceptions import ModelFileError
from .storage import load_arrays, save_arrays, storage_breakdown

__all__ = ["PlaceLocalizer", "register_model", "load", "MODEL_CLASSES"]

MODEL_CLASSES: dict[str, type["PlaceLocalizer"]] = {}


def register_model(cls: type["PlaceLocalizer"]) -> type["PlaceLocalizer"]:
    """Class decorator: make ``cls`` loadable by :func:`load` under its class name."""
    MODEL_CLASSES[cls.__name__] = cls
    return cls


class PlaceLocalizer(BaseEstimator):
    """Mixin with the storage and model-file behaviour shared by every method."""

    #: True when the method can return a ranked list of candidate places (R@K).
    supports_ranking: ClassVar[bool] = False
    #: The fitted attribute whose presence means "fitted".
    _fitted_marker: ClassVar[str] = "n_places_"

    # -- to implement -------------------------------------------------------------------------
    def _stored_arrays(self) -> dict[str, np.ndarray]:  # pragma: no cover - abstract
        raise NotImplementedError

    def _fitted_state(self) -> dict[str, Any]:
        return {}

    def _restore(self, arrays: dict[str, np.ndarray], state: dict[str, Any]) -> None:  # pragma: no cover
        raise NotImplementedError(f"{type(self).__name__} cannot be loaded from a file.")

    # -- shared -------------------------------------------------------------------------------
    def _check_queries(self, Q: Any) -> np.ndarray:
        """Validated query matrix (float32, 2-D, finite, the fitted dimension); raises if unfitted."""
        check_is_fitted(self, self._fitted_marker)
        return check_descriptors(Q, name="Q", n_features=self.n_features_in_)

    def rank(self, Q: Any, k: int = 10) -> np.ndarray:
        """Return the ``k`` most likely places per query, best first (shape (n_queries, k), int64)."""
        raise NotImplementedError(f"{type(self).__name__} does not rank candidates; use predict().")

    def predict_sequence(self, Q: Any, decoder: str = "hmm", **options: Any) -> np.ndarray:
        """Place of each query of one ordered sequence (a traverse), decoded over time.

        No extra stored bytes: the decoders read only this model's per-query output.

        Parameters
        ----------
        Q : array-like of shape (n_queries, n_features)
            Consecutive frames of one traverse, in order.
        decoder : {'hmm', 'median'}
            'hmm': online forward filtering over places with the per-place scores
            (:func:`btel.sequence_decoding.method_scores`, z-scored per frame) as emissions and
            forward motion as transitions (:class:`btel.sequence_decoding.HMMDecoder`; options
            ``temperature``, ``vmin``, ``vmax``, ``backward``, ``teleport``). 'median': the
            paper's filter on single-frame predictions (:func:`btel.sequence.filter_sequence`;
            option ``window``, default 5).

        Returns
        -------
        ndarray of shape (n_queries,), int64 in [0, N)
        """
        from .exceptions import InvalidParameterError

        if decoder == "median":
            from .sequence import filter_sequence

            unknown = set(options) - {"window"}
            if unknown:
                raise InvalidParameterError(f"decoder='median' takes only window; got {sorted(unknown)}.")
            return filter_sequence(self.predict(Q), int(options.get("window", 5)), n_places=int(self.n_places_))
        if decoder == "hmm":
            from .sequence_decoding import decode_sequence, emission_scores

            return decode_sequence(emission_scores(self, Q), **options)
        raise InvalidParameterError(f"decoder must be 'hmm' or 'median'; got {decoder!r}.")

    def storage_breakdown(self) -> dict[str, int]:
        """Bytes of each stored array that inference reads (SPEC §7).

        Returns
        -------
        dict of str to int
            Part name → bytes. ``sum(values) == nbytes``.
        """
        check_is_fitted(self, self._fitted_marker)
        return storage_breakdown(self._stored_arrays())

    @property
    def nbytes(self) -> int:
        """Total storage in bytes: the sum of :meth:`storage_breakdown`."""
        return int(sum(self.storage_breakdown().values()))

    def save(self, path: str | os.PathLike) -> Path:
        """Save the fitted model: its stored arrays plus a JSON header (no pickles).

        The file size exceeds :attr:`nbytes` only by the container overhead (a few KiB).
        """
        check_is_fitted(self, self._fitted_marker)
        params = {k: _jsonable(v) for k, v in self.get_params(deep=False).items()}
        header = {"model": type(self).__name__, "params": params, "state": self._fitted_state()}
        return save_arrays(path, self._stored_arrays(), header)


def load(path: str | os.PathLike) -> PlaceLocalizer:
    """Load a model saved by ``save``; the class is read from the file's header.

    Raises
    ------
    ModelFileError
        Missing, corrupt, truncated or foreign file, or an unknown model class.
    UnsupportedModelVersionError
        A file from a newer btel.
    """
    arrays, header = load_arrays(path)
    if header.get("kind") == "image-descriptor":
        raise ModelFileError(
            f"{str(path)!r} is a saved image descriptor, not a localization model; "
            "load it with btel.descriptors.load_descriptor(path)."
        )
    name = header.get("model")
    if name not in MODEL_CLASSES:
        # Baselines register themselves on import; import them before giving up.
        from . import methods  # noqa: F401  (registers every method)

    cls = MODEL_CLASSES.get(name)
    if cls is None:
        raise ModelFileError(f"{str(path)!r} holds a model of unknown type {name!r}; it was not written by this btel.")
    params = header.get("params", {})
    state = header.get("state", {})
    if not isinstance(params, dict) or not isinstance(state, dict):
        raise ModelFileError(f"{str(path)!r} has a corrupt header (params/state are not objects).")
    try:
        model = cls(**params)
        model._restore(arrays, state)
    except ModelFileError:
        raise
    except (KeyError, TypeError, ValueError, IndexError) as exc:
        raise ModelFileError(
            f"{str(path)!r} is inconsistent with a {name} model ({type(exc).__name__}: {exc}); "
            "the file is corrupt or was edited."
        ) from exc
    return model


def _jsonable(value: Any) -> Any:
    if isinstance(value, (np.integer,)):
        return int(value)
    if isinstance(value, (np.floating,)):
        return float(value)
    if isinstance(value, type):
        return np.dtype(value).name
    if isinstance(value, np.dtype):
        return value.name
    return value
