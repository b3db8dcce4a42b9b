"""HOG: histograms of oriented gradients on a small grey thumbnail (scikit-image).

Defaults reproduce the paper's Nordland descriptor: the grey image resized to 64×32 pixels, 9
orientations, 4×4-pixel cells, 2×2-cell blocks, L2-Hys block normalisation. On a 64×32 frame that
is 15×7 block positions × 2×2 cells × 9 bins = 3780 values.
"""

from __future__ import annotations

from typing import ClassVar

import numpy as np
from skimage.feature import hog

from ..core.validation import check_positive_int
from ..exceptions import InvalidParameterError
from ..core.limits import check_bytes
from .base import ImageDescriptor, check_pair, register_descriptor
from .images import resize_grey

__all__ = ["HOGDescriptor"]

_BLOCK_NORMS = ("L1", "L1-sqrt", "L2", "L2-Hys")


@register_descriptor
class HOGDescriptor(ImageDescriptor):
    """HOG of the grey image resized to a fixed size (stateless).

    Parameters
    ----------
    size : (int, int)
        Thumbnail ``(width, height)`` in pixels, OpenCV's order. Default (64, 32).
    orientations : int
        Orientation bins per cell.
    pixels_per_cell : (int, int)
        Cell ``(rows, cols)`` in pixels, scikit-image's order.
    cells_per_block : (int, int)
        Block ``(rows, cols)`` in cells.
    block_norm : {"L1", "L1-sqrt", "L2", "L2-Hys"}
        Block normalisation (scikit-image).

    Attributes
    ----------
    dim_ : int
        Descriptor length (set by fit; :attr:`output_dim` is available without fit).

    Examples
    --------
    >>> import numpy as np
    >>> X = HOGDescriptor().transform([np.zeros((32, 64), np.uint8)], progress=False)
    >>> X.shape, X.dtype
    ((1, 3780), dtype('float32'))
    """

    name: ClassVar[str] = "hog"

    def __init__(
        self,
        *,
        size: tuple[int, int] = (64, 32),
        orientations: int = 9,
        pixels_per_cell: tuple[int, int] = (4, 4),
        cells_per_block: tuple[int, int] = (2, 2),
        block_norm: str = "L2-Hys",
    ) -> None:
        self.size = size
        self.orientations = orientations
        self.pixels_per_cell = pixels_per_cell
        self.cells_per_block = cells_per_block
        self.block_norm = block_norm

    def _validate_params(self) -> None:
        check_pair(self.size, "size")
        check_positive_int(self.orientations, "orientations")
        check_pair(self.pixels_per_cell, "pixels_per_cell")
        check_pair(self.cells_per_block, "cells_per_block")
        if self.block_norm not in _BLOCK_NORMS:
            raise InvalidParameterError(f"block_norm must be one of {', '.join(_BLOCK_NORMS)}; got {self.block_norm!r}.")
        n_r, n_c = self._blocks()
        width, height = check_pair(self.size, "size")
        block_r, block_c = check_pair(self.cells_per_block, "cells_per_block")
        # One image: the resized image and its gradients (float64), the cell histograms and the
        # blocks, before the first pixel is read (a saved file may declare any size).
        per_image = 8.0 * (width * height * 4 + (n_r + block_r) * (n_c + block_c) * self.orientations
                           + n_r * n_c * block_r * block_c * self.orientations)
        check_bytes(per_image, f"HOG of size {width}×{height} with {self.orientations} orientations (one image)")

    def _blocks(self) -> tuple[int, int]:
        width, height = check_pair(self.size, "size")
        cell_r, cell_c = check_pair(self.pixels_per_cell, "pixels_per_cell")
        block_r, block_c = check_pair(self.cells_per_block, "cells_per_block")
        # scikit-image drops the partial cells at the right/bottom edge, then slides blocks by one cell.
        n_r, n_c = height // cell_r - block_r + 1, width // cell_c - block_c + 1
        if n_r < 1 or n_c < 1:
            raise InvalidParameterError(
                f"a {width}×{height} image holds no {block_r}×{block_c}-cell block of {cell_r}×{cell_c}-pixel "
                "cells; enlarge size or reduce pixels_per_cell / cells_per_block."
            )
        return n_r, n_c

    @property
    def thumbnail_size(self) -> tuple[int, int]:
        """Every image is resized to ``size`` = (width, height), whatever its aspect (warned when it
        distorts the images)."""
        return check_pair(self.size, "size")

    @property
    def output_dim(self) -> int:
        """Descriptor length: blocks × cells per block × orientations (3780 by default)."""
        n_r, n_c = self._blocks()
        block_r, block_c = self.cells_per_block
        return int(n_r * n_c * block_r * block_c * self.orientations)

    def _encode(self, grey: np.ndarray) -> np.ndarray:
        image = resize_grey(grey, tuple(self.size))
        return hog(
            image,
            orientations=self.orientations,
            pixels_per_cell=tuple(self.pixels_per_cell),
            cells_per_block=tuple(self.cells_per_block),
            block_norm=self.block_norm,
            feature_vector=True,
        )
