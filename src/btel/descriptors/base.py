"""The interface every image descriptor implements, and the registry by short name.

A descriptor turns images into one global descriptor per image, ``(n, dim)`` float32 — the
``X`` every localizer in btel fits on. It is a scikit-learn style estimator:

- ``__init__`` only stores keyword arguments (so ``get_params``/``clone`` work);
- ``fit(images)`` learns what the descriptor needs (a vocabulary, a PCA) and returns ``self``;
  for stateless descriptors it only checks the parameters;
- ``transform(images)`` returns ``(n, dim)`` float32; ``output_dim`` (and ``dim_`` after fit) is dim;
- ``save(path)`` / ``ImageDescriptor.load(path)`` keep the fitted state as plain arrays plus a
  JSON header (:func:`btel.core.modelfile.save_arrays`), never pickles.

Subclasses set ``name`` (the registry key) and implement ``_encode(grey)`` (one image →
``_raw_dim()`` floats) and, when they learn something, ``_fit``, ``_project`` (a batch of raw
vectors → final vectors), ``_stored_arrays``, ``_fitted_state`` and ``_restore``.
"""

from __future__ import annotations

import importlib
import json
import os
import warnings
from collections import Counter
from collections.abc import Iterator
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
from sklearn.base import BaseEstimator

from ..core.validation import check_is_fitted, check_positive_int
from ..exceptions import InvalidParameterError, ModelFileError
from ..core.modelfile import load_arrays, save_arrays
from ..core.limits import check_bytes, check_count, memory_limit
from ..core.threads import one_blas_thread
from .images import ImageInput, as_image_list, iter_grey

__all__ = [
    "DescriptorWarning",
    "ImageDescriptor",
    "DESCRIPTORS",
    "register_descriptor",
    "get_descriptor",
    "load_descriptor",
    "single_blas_thread",
]

#: Header ``kind`` that marks a btel file as a saved image descriptor (not a localizer model).
FILE_KIND = "image-descriptor"

#: Registry: short name → descriptor class (filled by :func:`register_descriptor`).
DESCRIPTORS: dict[str, type["ImageDescriptor"]] = {}


#: An image whose aspect ratio differs from the thumbnail's by more than this share is distorted.
_ASPECT_SLACK = 0.05


class DescriptorWarning(UserWarning):
    """Something a descriptor did to the images that the user did not ask for (a distorting
    resize, mixed image sizes, a PCA capped below the requested size)."""


#: The descriptors btel ships: name → module. Each registers itself when imported; they import OpenCV,
#: scikit-image and scikit-learn, so they are imported when a descriptor is first asked for by name
#: (:func:`registered`), not with the package (reading a descriptor matrix needs none of them).
_BUILT_IN = {"densevlad": ".densevlad", "hog": ".hog", "patchnorm": ".patchnorm"}


def registered() -> dict[str, type["ImageDescriptor"]]:
    """:data:`DESCRIPTORS`, the built-in descriptors imported (so registered) first."""
    for module in _BUILT_IN.values():
        importlib.import_module(module, __package__)
    return DESCRIPTORS


def register_descriptor(cls: type["ImageDescriptor"]) -> type["ImageDescriptor"]:
    """Class decorator: make ``cls`` available to :func:`get_descriptor` under ``cls.name``."""
    DESCRIPTORS[cls.name] = cls
    return cls


class ImageDescriptor(BaseEstimator):
    """Base class of the image front ends (HOG, patch normalisation, DenseVLAD)."""

    #: Registry key, e.g. ``"hog"``.
    name: ClassVar[str] = ""
    #: True when ``transform`` needs ``fit`` first (a learned vocabulary or projection).
    requires_fit: ClassVar[bool] = False
    #: Images encoded per batch before ``_project`` (bounds memory of the raw vectors).
    _batch_size: ClassVar[int] = 256

    # -- to implement ------------------------------------------------------------------------
    def _validate_params(self) -> None:  # pragma: no cover - every subclass overrides
        """Raise :class:`InvalidParameterError` for a bad parameter."""

    def _encode(self, grey: np.ndarray) -> np.ndarray:  # pragma: no cover - abstract
        """One grey image (uint8 or float32 in [0, 1]) → raw vector of ``_raw_dim()`` floats."""
        raise NotImplementedError

    def _raw_dim(self) -> int:
        return self.output_dim

    def _project(self, raw: np.ndarray) -> np.ndarray:
        """A batch of raw vectors (m, raw_dim) → final descriptors (m, dim). Identity by default."""
        return raw

    def _fit(self, items: list, progress: bool) -> np.ndarray | None:
        """Learn state from ``items``; may return the transformed training images to save a pass."""
        return None

    def _stored_arrays(self) -> dict[str, np.ndarray]:
        return {}

    def _fitted_state(self) -> dict[str, Any]:
        return {}

    def _restore(self, arrays: dict[str, np.ndarray], state: dict[str, Any]) -> None:
        self._validate_params()
        self.dim_ = self.output_dim

    @property
    def output_dim(self) -> int:  # pragma: no cover - every subclass overrides
        """Length of one descriptor."""
        raise NotImplementedError

    @property
    def thumbnail_size(self) -> tuple[int, int] | None:
        """``(width, height)`` every image is resized to before encoding, or None (kept as is)."""
        return None

    def _watch_sizes(self, greys: Iterator[np.ndarray], sizes: Counter) -> Iterator[np.ndarray]:
        """Pass the images through, counting their (width, height)."""
        for grey in greys:
            sizes[(int(grey.shape[1]), int(grey.shape[0]))] += 1
            yield grey

    def _warn_about_sizes(self, sizes: Counter) -> None:
        """Say (as a :class:`DescriptorWarning`) when images came in several sizes, or when the fixed
        thumbnail size distorts them: both change the descriptors silently otherwise."""
        if len(sizes) > 1:
            listed = ", ".join(f"{w}×{h} ({n})" for (w, h), n in sizes.most_common(4))
            more = f" and {len(sizes) - 4} more" if len(sizes) > 4 else ""
            warnings.warn(
                f"{self.name}: the images come in {len(sizes)} sizes ({listed}{more}); descriptors of differently "
                "sized images of one place may differ. Give every image the same size.",
                DescriptorWarning, stacklevel=3)
        target = self.thumbnail_size
        if target is None or not sizes:
            return
        width, height = target
        aspect = width / height
        distorted = [(w, h) for (w, h) in sizes if abs((w / h) / aspect - 1.0) > _ASPECT_SLACK]
        if distorted:
            w, h = max(distorted, key=lambda wh: sizes[wh])
            suggestion = (round(height * w / h / 8) * 8 or 8, height)
            warnings.warn(
                f"{self.name} resizes every image to {width}×{height} (aspect {aspect:.2f}), but these images are "
                f"{w}×{h} (aspect {w / h:.2f}): they are stretched. Pass a size with their aspect, e.g. "
                f"size=({suggestion[0]}, {suggestion[1]}) (btel extract --size {suggestion[0]}x{suggestion[1]}).",
                DescriptorWarning, stacklevel=3)

    # -- shared ------------------------------------------------------------------------------
    def fit(self, images: ImageInput = None, y: Any = None, *, progress: bool = True) -> "ImageDescriptor":
        """Learn the descriptor's state from map images (a no-op check for stateless ones).

        Parameters
        ----------
        images : folder, sequence of image paths or arrays
            Training (map) images. Ignored by stateless descriptors.
        y : ignored
            Present for scikit-learn compatibility.
        progress : bool
            Show a progress bar (only on a terminal).

        Returns
        -------
        self
        """
        self._validate_params()
        if self.requires_fit:
            self._fit(as_image_list(images), progress)
        else:
            self.dim_ = self.output_dim
        return self

    def transform(self, images: ImageInput, *, progress: bool = True) -> np.ndarray:
        """Describe each image.

        Parameters
        ----------
        images : folder, sequence of image paths or arrays, or stacked ndarray
            See :mod:`btel.descriptors.images` for the accepted forms.
        progress : bool
            Show a progress bar (only on a terminal).

        Returns
        -------
        X : ndarray of shape (n_images, output_dim), dtype float32
            Row i describes image i.

        Raises
        ------
        NotFittedError
            A descriptor that learns state was not fitted (or loaded).
        DataNotFoundError
            A missing or undecodable image file (named in the message).
        InvalidParameterError
            A bad parameter or image array.
        """
        items = as_image_list(images)
        if self.requires_fit:
            check_is_fitted(self, "dim_")
        else:
            self._validate_params()
        n = len(items)
        # The widths come from the parameters, which a saved descriptor file sets: 594 bytes asking for
        # 48,000 HOG orientations meant 80 MB an image. Refused from the shapes, before any image is read.
        check_count(float(n) * self.output_dim, 4, f"{n} {self.name} descriptors of {self.output_dim} values")
        row = 4.0 * self._raw_dim()
        check_bytes(row, f"one {self.name} descriptor of {self._raw_dim()} values before projection")
        batch = max(1, min(n, self._batch_size, int(memory_limit() // 4 // row)))
        out = np.empty((n, self.output_dim), dtype=np.float32)
        raw = np.empty((batch, self._raw_dim()), dtype=np.float32)
        sizes: Counter = Counter()
        greys = self._watch_sizes(iter_grey(items, progress=progress, desc=self.name), sizes)
        for start in range(0, n, raw.shape[0]):
            stop = min(n, start + raw.shape[0])
            with single_blas_thread():
                for row in range(stop - start):
                    raw[row] = self._encode(next(greys))
            # The batch projection is one large product: there BLAS threads pay off.
            out[start:stop] = self._project(raw[: stop - start])
        self._warn_about_sizes(sizes)
        return out

    def fit_transform(self, images: ImageInput, y: Any = None, *, progress: bool = True) -> np.ndarray:
        """``fit(images).transform(images)``, reusing work done in fit where the descriptor can.

        Returns
        -------
        X : ndarray of shape (n_images, output_dim), dtype float32
        """
        self._validate_params()
        items = as_image_list(images)
        if self.requires_fit:
            done = self._fit(items, progress)
            if done is not None:
                return done
        else:
            self.dim_ = self.output_dim
        return self.transform(items, progress=progress)

    def save(self, path: str | os.PathLike, *, overwrite: bool | None = None) -> Path:
        """Save the parameters and fitted state: plain arrays plus a JSON header, no pickles.

        Written atomically (:func:`btel.core.modelfile.save_arrays`): an existing btel file is replaced, any other
        kept; ``overwrite=True`` replaces anything, ``False`` nothing.

        Raises
        ------
        NotFittedError
            A descriptor that learns state was not fitted.
        OutputExistsError
            ``path`` exists and is kept (``overwrite`` False, or None and not a btel file).
        """
        if self.requires_fit:
            check_is_fitted(self, "dim_")
        else:
            self._validate_params()
        params = {k: _jsonable(k, v) for k, v in self.get_params(deep=False).items()}
        header = {"kind": FILE_KIND, "descriptor": self.name, "params": params, "state": self._fitted_state()}
        return save_arrays(path, self._stored_arrays(), header, overwrite=overwrite)

    @classmethod
    def load(cls, path: str | os.PathLike) -> "ImageDescriptor":
        """Load a descriptor written by :meth:`save`; the class is read from the file.

        Called on a subclass (``DenseVLADDescriptor.load``) the file must hold that kind.

        Raises
        ------
        ModelFileError
            Missing, corrupt or foreign file, or a different descriptor than requested.
        """
        path = Path(path)
        if not path.exists():
            raise ModelFileError(
                f"descriptor file {str(path)!r} does not exist. Fit a descriptor and call .save(path) first."
            )
        arrays, header = load_arrays(path)
        if header.get("kind") != FILE_KIND:
            raise ModelFileError(
                f"{str(path)!r} is a btel file but not an image descriptor"
                f"{' (it holds a ' + repr(header['model']) + ' model; load it with btel.load)' if 'model' in header else ''}."
            )
        name = header.get("descriptor")
        klass = registered().get(name) if isinstance(name, str) else None
        if klass is None:
            raise ModelFileError(f"{str(path)!r} holds an unknown descriptor {name!r}; it was not written by this btel.")
        if cls is not ImageDescriptor and not issubclass(klass, cls):
            raise ModelFileError(f"{str(path)!r} holds a {name!r} descriptor, not a {cls.name!r} one.")
        params, state = header.get("params", {}), header.get("state", {})
        if not isinstance(params, dict) or not isinstance(state, dict):
            raise ModelFileError(f"{str(path)!r} has a corrupt header (params/state are not objects).")
        try:
            # JSON has no tuples; the size/cell parameters are tuples in __init__.
            obj = klass(**{k: tuple(v) if isinstance(v, list) else v for k, v in params.items()})
            obj._restore(arrays, state)
        except Exception as exc:  # untrusted input: any failure (OverflowError, RecursionError…) is a bad file
            raise ModelFileError(
                f"{str(path)!r} is inconsistent with a {name} descriptor ({type(exc).__name__}: {exc}); "
                "the file is corrupt or was edited."
            ) from exc
        return obj


def single_blas_thread() -> Any:
    """Context manager: numpy's BLAS on one thread while encoding images one at a time.

    Encoding makes many small matrix products per image (a few dozen to ~13k descriptors against
    128 centroids). Waking BLAS worker threads costs more than such a product, and on a busy
    machine it costs milliseconds each (measured: a 38×128 by 128×128 product took 22 ms with two
    OpenBLAS threads under load against 0.02 ms on one).
    """
    return one_blas_thread()


def get_descriptor(name: str, **params: Any) -> ImageDescriptor:
    """Create a descriptor by short name: ``get_descriptor("hog", orientations=12)``.

    Parameters
    ----------
    name : str
        One of ``DESCRIPTORS`` (``"densevlad"``, ``"hog"``, ``"patchnorm"``); case-insensitive.
    **params
        Keyword arguments of that descriptor class.

    Raises
    ------
    InvalidParameterError
        Unknown name, or a parameter the class does not take.
    """
    key = name.lower().replace("-", "").replace("_", "") if isinstance(name, str) else name
    cls = registered().get(key)
    if cls is None:
        raise InvalidParameterError(f"unknown descriptor {name!r}; choose one of {', '.join(sorted(DESCRIPTORS))}.")
    try:
        return cls(**params)
    except TypeError as exc:
        accepted = ", ".join(cls._get_param_names())
        raise InvalidParameterError(f"bad parameters for descriptor {cls.name!r} ({exc}); it takes: {accepted}.") from exc


def load_descriptor(path: str | os.PathLike) -> ImageDescriptor:
    """Load any saved descriptor (same as :meth:`ImageDescriptor.load`)."""
    return ImageDescriptor.load(path)


def check_pair(value: object, name: str) -> tuple[int, int]:
    """Return ``value`` as a pair of positive ints or raise :class:`InvalidParameterError`."""
    if not isinstance(value, (tuple, list)) or len(value) != 2:
        raise InvalidParameterError(f"{name} must be a pair of positive integers; got {value!r}.")
    return check_positive_int(value[0], f"{name}[0]"), check_positive_int(value[1], f"{name}[1]")


def _scalar(value: Any) -> Any:
    if isinstance(value, np.integer):
        return int(value)
    if isinstance(value, np.floating):
        return float(value)
    return value


def _jsonable(key: str, value: Any) -> Any:
    value = [_scalar(v) for v in value] if isinstance(value, (tuple, list)) else _scalar(value)
    try:
        json.dumps(value)
    except TypeError:
        if key == "random_state":
            # A RandomState/Generator only matters for refitting; the fitted state is in the file.
            return None
        raise InvalidParameterError(f"parameter {key}={value!r} cannot be saved (not JSON-serialisable).") from None
    return value
