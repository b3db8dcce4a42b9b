"""Patch-normalised thumbnails, the SeqSLAM front end (Milford & Wyeth 2012, OpenSeqSLAM).

The grey image is resized to 64×32 pixels and cut into non-overlapping 8×8 patches; each patch
is shifted to zero mean and scaled to unit standard deviation, which removes local brightness
and contrast (day/night, seasons) and keeps local structure. 64×32 pixels → 2048 values.

OpenSeqSLAM stores ``127 + round(z)`` as uint8 (btel's storage rule counts N×2048 bytes for SeqSLAM); this
module returns the float z-scores and leaves any quantisation to the caller.
"""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np

from ..core.validation import check_positive_int
from ..exceptions import InvalidParameterError
from .base import ImageDescriptor, check_pair, register_descriptor
from .images import resize_grey

__all__ = ["patch_normalise", "PatchNormDescriptor"]


def patch_normalise(image: Any, patch_size: int = 8, *, eps: float = 1e-6) -> np.ndarray:
    """Scale each non-overlapping ``patch_size``² patch to zero mean and unit standard deviation.

    Parameters
    ----------
    image : array-like of shape (H, W)
        A grey image; H and W must be multiples of ``patch_size``.
    patch_size : int
        Side of the square patches in pixels.
    eps : float
        A patch whose standard deviation is ≤ ``eps`` (in the image's units) is flat: it becomes
        zeros instead of amplified rounding noise.

    Returns
    -------
    ndarray of shape (H, W), dtype float32
        Every non-flat patch has mean 0 and standard deviation 1 (population std, ``ddof=0``;
        MATLAB's ``std`` in OpenSeqSLAM uses n−1, a constant factor of √(63/64) for 8×8 patches
        that changes no ranking).

    Raises
    ------
    InvalidParameterError
        Not a finite 2-D numeric array, or a side not divisible by ``patch_size``.
    """
    size = check_positive_int(patch_size, "patch_size")
    arr = np.asarray(image)
    if arr.ndim != 2 or arr.dtype.kind not in "biuf":
        raise InvalidParameterError(f"patch_normalise needs a 2-D numeric grey image; got shape {arr.shape}, dtype {arr.dtype}.")
    height, width = arr.shape
    if height % size or width % size or height == 0 or width == 0:
        raise InvalidParameterError(
            f"image of {width}×{height} pixels is not a whole number of {size}×{size} patches; "
            "resize it to a multiple of patch_size first."
        )
    pixels = arr.astype(np.float64)
    if not np.isfinite(pixels).all():
        raise InvalidParameterError("patch_normalise got NaN or infinite pixel values.")
    # (rows of patches, patch row, cols of patches, patch col): axes 1 and 3 run inside a patch.
    patches = pixels.reshape(height // size, size, width // size, size)
    mean = patches.mean(axis=(1, 3), keepdims=True)
    std = patches.std(axis=(1, 3), keepdims=True)
    centred = patches - mean
    out = np.divide(centred, std, out=np.zeros_like(centred), where=std > eps)
    return out.reshape(height, width).astype(np.float32)


@register_descriptor
class PatchNormDescriptor(ImageDescriptor):
    """SeqSLAM's patch-normalised grey thumbnail, flattened row by row (stateless).

    Parameters
    ----------
    size : (int, int)
        Thumbnail ``(width, height)`` in pixels, OpenCV's order; both multiples of ``patch_size``.
    patch_size : int
        Side of the normalisation patches in pixels.

    Attributes
    ----------
    dim_ : int
        ``width × height`` (2048 by default), set by fit; :attr:`output_dim` works without fit.
    """

    name: ClassVar[str] = "patchnorm"

    def __init__(self, *, size: tuple[int, int] = (64, 32), patch_size: int = 8) -> None:
        self.size = size
        self.patch_size = patch_size

    def _validate_params(self) -> None:
        width, height = check_pair(self.size, "size")
        patch = check_positive_int(self.patch_size, "patch_size")
        if width % patch or height % patch:
            raise InvalidParameterError(
                f"size {width}×{height} is not a whole number of {patch}×{patch} patches; "
                "choose a size that is a multiple of patch_size."
            )

    @property
    def thumbnail_size(self) -> tuple[int, int]:
        """Every image is resized to ``size`` = (width, height), whatever its aspect (warned when it
        distorts the images)."""
        return check_pair(self.size, "size")

    @property
    def output_dim(self) -> int:
        """``width × height`` of the thumbnail (2048 by default)."""
        self._validate_params()
        width, height = self.size
        return int(width * height)

    def _encode(self, grey: np.ndarray) -> np.ndarray:
        return patch_normalise(resize_grey(grey, tuple(self.size)), self.patch_size).ravel()
