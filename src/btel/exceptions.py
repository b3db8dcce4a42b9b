"""Every failure btel names, in one place.

Each error derives from :class:`BTELError` and from the built-in exception a user would
catch anyway (``ValueError``, ``OSError``), so ``except ValueError`` keeps working.
Messages say what is wrong and what to do about it.

:class:`NotFittedError` also derives from scikit-learn's, so it is built on first use (module
``__getattr__``): importing scikit-learn costs about a second, and loading a model and answering
queries never needs it.
"""

from __future__ import annotations

import threading
from typing import TYPE_CHECKING, Any

__all__ = [
    "BTELError",
    "InvalidDescriptorsError",
    "DimensionMismatchError",
    "NotEnoughPlacesError",
    "InvalidParameterError",
    "BudgetTooSmallError",
    "BudgetExceededError",
    "ModelFileError",
    "UnsupportedModelVersionError",
    "NotFittedError",
    "DataNotFoundError",
    "MissingDependencyError",
    "ResourceLimitError",
    "InvalidAnswerError",
    "OutputExistsError",
    "CollidingCodesWarning",
]


class BTELError(Exception):
    """Base class of every error raised by btel."""


class InvalidDescriptorsError(BTELError, ValueError):
    """Descriptors are empty, not 2-D, not numeric, or contain NaN/inf."""


class DimensionMismatchError(BTELError, ValueError):
    """Query descriptors have a different dimension from the map the model was fitted on."""


class NotEnoughPlacesError(BTELError, ValueError):
    """Fewer than two places (or a region too short) to build an index over."""


class InvalidParameterError(BTELError, ValueError):
    """A parameter has a value outside its valid range."""


class BudgetTooSmallError(BTELError, ValueError):
    """No configuration of the method fits in the requested number of bytes.

    Attributes
    ----------
    budget : int
        The requested budget in bytes.
    minimum : int
        The smallest number of bytes any configuration needs.
    """

    def __init__(self, message: str, *, budget: int, minimum: int) -> None:
        super().__init__(message)
        self.budget = budget
        self.minimum = minimum


class ModelFileError(BTELError, OSError):
    """A model file is missing, truncated, corrupt, or not a btel model."""


class UnsupportedModelVersionError(ModelFileError):
    """A model file was written by a newer btel (a format version this one cannot read)."""


class DataNotFoundError(BTELError, FileNotFoundError):
    """A data folder or file does not exist or holds nothing btel can read."""


class MissingDependencyError(BTELError, ImportError):
    """An optional dependency (e.g. Dask for ``backend='dask'``) is not installed."""


class BudgetExceededError(BTELError, RuntimeError):
    """A fitted model stores more bytes than its budget (a bug in that method's budget fitting)."""


class ResourceLimitError(BTELError, ValueError):
    """An input declares more memory or work than btel's limit allows (see :mod:`btel.core.limits`;
    raise the limit with the ``BTEL_MEMORY_LIMIT`` environment variable)."""


class InvalidAnswerError(BTELError, ValueError):
    """A fitted model produced non-finite scores or a place outside [0, N) (usually weights that
    overflow float32: a damaged or hostile model file, or a fit on extreme values)."""


class OutputExistsError(BTELError, FileExistsError):
    """An output file or run folder exists (or another writer took it first) and replacing it was not
    asked for (``overwrite=False``; on the command line, no ``--overwrite``): nothing was replaced."""


class CollidingCodesWarning(UserWarning):
    """The budget leaves a quantiser codes of fewer than log2 N bits: map rows must share codes. A warning,
    not an error (the model fits the budget); filter it by this class where such fits are expected."""


_NOT_FITTED_LOCK = threading.Lock()

if TYPE_CHECKING:  # pragma: no cover - what __getattr__ builds, for type checkers
    from sklearn.exceptions import NotFittedError as _SklearnNotFittedError

    class NotFittedError(BTELError, _SklearnNotFittedError):
        """A model was used before ``fit`` (also a scikit-learn ``NotFittedError``)."""


def __getattr__(name: str) -> Any:
    """Build :class:`NotFittedError` on first access (it imports scikit-learn); any other name is unknown."""
    if name != "NotFittedError":
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    with _NOT_FITTED_LOCK:
        if "NotFittedError" not in globals():
            from sklearn.exceptions import NotFittedError as sklearn_not_fitted

            cls = type("NotFittedError", (BTELError, sklearn_not_fitted), {
                "__doc__": "A model was used before ``fit`` (also a scikit-learn ``NotFittedError``).",
                "__module__": __name__})
            globals()["NotFittedError"] = cls
    return globals()["NotFittedError"]
