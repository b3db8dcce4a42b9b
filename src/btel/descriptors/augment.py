"""Augmented views of map images, for multi-exemplar training (``BTELocalizer.fit(X, places)``).

Each map image yields itself plus photometric and geometric variants — brightness and contrast
changes and small horizontal shifts (a camera a little off the original line) — all labelled with
the image's place. Describe the views with any front end and fit with the labels::

    views, places = augmented_views("map/", brightness=(0.7, 1.3), shifts=(4,))
    X = extract_descriptors(views, "hog")
    model = BTELocalizer(budget="64KB").fit(X, places)

The model's bytes do not grow with the number of views (the classifiers are the same size); fit
time grows linearly. Only map images are augmented; queries are never read.
"""

from __future__ import annotations

import numbers
from typing import Sequence

from .images import ImageInput, as_float_grey, as_image_list, iter_grey  # isort: skip - first: OpenCV's pixel cap
import cv2  # noqa: E402
import numpy as np

from ..exceptions import InvalidParameterError

__all__ = ["augmented_views"]


def _factors(values: Sequence[float], name: str) -> tuple[float, ...]:
    out = tuple(values)
    for v in out:
        if isinstance(v, bool) or not isinstance(v, numbers.Real) or not np.isfinite(v) or v <= 0:
            raise InvalidParameterError(f"{name} factors must be finite numbers > 0; got {v!r}.")
    return out


def augmented_views(
    images: ImageInput,
    *,
    brightness: Sequence[float] = (0.7, 1.3),
    contrast: Sequence[float] = (0.6, 1.4),
    shifts: Sequence[int] = (3,),
    progress: bool = True,
) -> tuple[list[np.ndarray], np.ndarray]:
    """Every image plus its brightness, contrast and shifted variants, with place labels.

    Parameters
    ----------
    images : folder, sequence of paths or arrays
        Map images in route order (image i is place i).
    brightness : sequence of float > 0
        Grey values multiplied by each factor (clipped to the valid range).
    contrast : sequence of float > 0
        Deviations from the image mean multiplied by each factor.
    shifts : sequence of int ≥ 1
        Horizontal shifts in pixels, each applied left and right (border pixels replicated).
    progress : bool
        Progress bar while reading the images.

    Returns
    -------
    views : list of ndarray of shape (H, W), float32 in [0, 1]
        ``1 + len(brightness) + len(contrast) + 2·len(shifts)`` views per image, image by image.
    places : ndarray of shape (len(views),), int64
        The place (source image index) of each view.
    """
    gains = _factors(brightness, "brightness")
    contrasts = _factors(contrast, "contrast")
    offsets = tuple(shifts)
    for s in offsets:
        if isinstance(s, bool) or not isinstance(s, numbers.Integral) or s < 1:
            raise InvalidParameterError(f"shifts must be whole pixels ≥ 1; got {s!r}.")
    items = as_image_list(images)
    views: list[np.ndarray] = []
    places: list[int] = []
    for i, grey in enumerate(iter_grey(items, progress=progress, desc="augment")):
        g = as_float_grey(grey)
        own: list[np.ndarray] = [g]
        own += [np.clip(g * k, 0.0, 1.0) for k in gains]
        mean = float(g.mean())
        own += [np.clip(mean + (g - mean) * k, 0.0, 1.0) for k in contrasts]
        for s in offsets:
            for sign in (-1, 1):
                shift = np.float32([[1, 0, sign * s], [0, 1, 0]])
                own.append(cv2.warpAffine(g, shift, (g.shape[1], g.shape[0]), borderMode=cv2.BORDER_REPLICATE))
        views += own
        places += [i] * len(own)
    return views, np.asarray(places, dtype=np.int64)

