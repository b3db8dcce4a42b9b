"""Reading images and turning every accepted image form into one grey array.

An *image* given to a descriptor is either a path to a file OpenCV can decode or an ndarray:
grey ``(H, W)``, grey ``(H, W, 1)``, colour ``(H, W, 3)`` in **RGB** order, or ``(H, W, 4)`` RGBA.
Pixel values are ``uint8`` (0..255), ``uint16`` (0..65535), ``bool``, other integers in 0..255,
or floats in [0, 1] (the scikit-image convention). A collection of images is a list (or any
iterable) of those, a folder (every image in it, see :func:`list_images`), or an array stacked
along its first axis ``(N, H, W)`` / ``(N, H, W, C)``.

Internally every image becomes a 2-D grey array that is either ``uint8`` or ``float32`` in
[0, 1]; each descriptor then converts to what its library needs.
"""

from __future__ import annotations

import os
import re
from pathlib import Path
from typing import Any, Iterator, Sequence

import cv2
import numpy as np
from tqdm.auto import tqdm

from ..exceptions import DataNotFoundError, InvalidParameterError

__all__ = [
    "IMAGE_EXTENSIONS",
    "ImageInput",
    "list_images",
    "read_image",
    "to_grey",
    "as_image_list",
    "iter_grey",
    "resize_grey",
]

#: File name endings :func:`list_images` picks up (compared case-insensitively).
IMAGE_EXTENSIONS: tuple[str, ...] = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".ppm")

#: What descriptors accept as "images": a folder, or a sequence of paths / ndarrays.
ImageInput = Any


def _natural_key(path: Path) -> tuple:
    # "2.jpg" before "10.jpg": digit runs compare as numbers. re.split with a capture group puts
    # text at even and numbers at odd positions, so equal positions always hold equal types.
    parts = re.split(r"(\d+)", path.name.lower())
    return tuple(int(p) if i % 2 else p for i, p in enumerate(parts)) + (path.name,)


def list_images(folder: str | os.PathLike) -> list[Path]:
    """Image files directly inside ``folder``, in natural order.

    Natural order compares runs of digits as numbers (``2.jpg`` before ``10.jpg``), so route
    order survives file names without zero padding. Hidden files (``.name``) are skipped.

    Parameters
    ----------
    folder : str or path-like
        A folder of ``.png``, ``.jpg``, ``.jpeg``, ``.bmp``, ``.tif``, ``.tiff`` or ``.ppm`` files
        (any letter case). Sub-folders are not searched.

    Returns
    -------
    list of pathlib.Path
        At least one path.

    Raises
    ------
    DataNotFoundError
        The folder does not exist, is a file, or holds no image files.
    """
    path = Path(folder)
    if not path.exists():
        raise DataNotFoundError(f"image folder {str(path)!r} does not exist. Check the path.")
    if not path.is_dir():
        raise DataNotFoundError(
            f"{str(path)!r} is a file, not a folder of images. Pass its folder, or a list of image paths."
        )
    files = [
        p
        for p in path.iterdir()
        if p.is_file() and not p.name.startswith(".") and p.suffix.lower() in IMAGE_EXTENSIONS
    ]
    if not files:
        others = sorted(p.name for p in path.iterdir())[:3]
        seen = f" (it holds: {', '.join(others)}{', ...' if len(others) == 3 else ''})" if others else " (it is empty)"
        raise DataNotFoundError(
            f"no images in folder {str(path)!r}{seen}. btel reads files ending in "
            f"{', '.join(IMAGE_EXTENSIONS)}."
        )
    return sorted(files, key=_natural_key)


def read_image(path: str | os.PathLike, *, grey: bool = False) -> np.ndarray:
    """Decode one image file with OpenCV.

    Parameters
    ----------
    path : str or path-like
        Any format OpenCV decodes (PNG, JPEG, BMP, TIFF, PPM, ...). 16-bit files are reduced to
        8 bits by OpenCV.
    grey : bool
        Decode straight to grey (OpenCV's luminance conversion) instead of colour.

    Returns
    -------
    image : ndarray of dtype uint8
        Shape ``(H, W)`` when ``grey``, else ``(H, W, 3)`` in RGB order.

    Raises
    ------
    DataNotFoundError
        The file does not exist, is empty, or OpenCV cannot decode it (the message names the file).
    """
    path = Path(path)
    if not path.exists():
        raise DataNotFoundError(f"image file {str(path)!r} does not exist.")
    if not path.is_file():
        raise DataNotFoundError(f"{str(path)!r} is a folder, not an image file.")
    # np.fromfile + imdecode instead of cv2.imread: imread cannot open non-ASCII paths on Windows
    # and gives no reason when it fails.
    data = np.fromfile(path, dtype=np.uint8)
    if data.size == 0:
        raise DataNotFoundError(f"image file {str(path)!r} is empty (0 bytes). Remove or replace it.")
    flags = cv2.IMREAD_GRAYSCALE if grey else cv2.IMREAD_COLOR
    try:
        image = cv2.imdecode(data, flags)
    except cv2.error:
        image = None
    if image is None:
        raise DataNotFoundError(
            f"OpenCV cannot decode {str(path)!r} as an image (corrupt, truncated or unsupported "
            "format). Remove or replace that file."
        )
    if not grey:
        image = cv2.cvtColor(image, cv2.COLOR_BGR2RGB)
    return image


def to_grey(image: Any, *, name: str = "image") -> np.ndarray:
    """Convert one image array to grey.

    Parameters
    ----------
    image : array-like of shape (H, W), (H, W, 1), (H, W, 3) RGB or (H, W, 4) RGBA
        uint8, uint16, bool, integers in 0..255, or floats in [0, 1].
    name : str
        What to call the image in error messages.

    Returns
    -------
    grey : ndarray of shape (H, W), dtype uint8 or float32
        uint8 input stays uint8 (0..255); everything else becomes float32 in [0, 1].

    Raises
    ------
    InvalidParameterError
        Wrong shape, non-numeric dtype, NaN/inf, or values outside the dtype's range.
    """
    arr = np.asarray(image)
    if arr.dtype == object or arr.dtype.kind not in "biuf":
        raise InvalidParameterError(f"{name} has dtype {arr.dtype}; images must be numeric arrays (uint8 preferred).")
    if arr.ndim == 3 and arr.shape[2] == 1:
        arr = arr[:, :, 0]
    if not (arr.ndim == 2 or (arr.ndim == 3 and arr.shape[2] in (3, 4))):
        raise InvalidParameterError(
            f"{name} has shape {arr.shape}; an image must be (H, W) grey, (H, W, 3) RGB or (H, W, 4) RGBA."
        )
    if arr.shape[0] == 0 or arr.shape[1] == 0:
        raise InvalidParameterError(f"{name} is empty (shape {arr.shape}).")
    if arr.dtype == np.uint8:
        pass
    elif arr.dtype == np.uint16:
        arr = arr.astype(np.float32) / np.float32(65535.0)
    elif arr.dtype == bool:
        arr = arr.astype(np.float32)
    elif arr.dtype.kind in "iu":
        if arr.min() < 0 or arr.max() > 255:
            raise InvalidParameterError(
                f"{name} has integer values in [{arr.min()}, {arr.max()}]; integer images must lie in "
                "0..255 (or be uint16). Convert it to uint8."
            )
        arr = arr.astype(np.uint8)
    else:
        arr = arr.astype(np.float32, copy=False)
        if not np.isfinite(arr).all():
            raise InvalidParameterError(f"{name} contains NaN or infinite pixel values.")
        lo, hi = float(arr.min()), float(arr.max())
        # A float image outside [0, 1] is almost always 0..255 data; guessing its scale would make
        # results depend on image content, so ask for an explicit conversion instead.
        if lo < -1e-6 or hi > 1.0 + 1e-6:
            raise InvalidParameterError(
                f"{name} is a float image with values in [{lo:g}, {hi:g}]; float images must lie in "
                "[0, 1]. Divide 0..255 images by 255 or pass them as uint8."
            )
        arr = np.clip(arr, 0.0, 1.0)
    if arr.ndim == 3:
        code = cv2.COLOR_RGB2GRAY if arr.shape[2] == 3 else cv2.COLOR_RGBA2GRAY
        arr = cv2.cvtColor(np.ascontiguousarray(arr), code)
    return np.ascontiguousarray(arr)


def as_image_list(images: ImageInput) -> list:
    """Normalise the accepted forms of "some images" to a non-empty list of paths or arrays.

    Parameters
    ----------
    images : folder path, image file path, sequence of paths / arrays, or stacked ndarray
        A folder expands to :func:`list_images`; one file path to a one-image list; an ndarray of
        shape (N, H, W) or (N, H, W, C) to its N images.

    Returns
    -------
    list
        Paths (:class:`pathlib.Path`) and/or ndarrays, in the given order.

    Raises
    ------
    DataNotFoundError
        A folder or file that does not exist, or a folder without images.
    InvalidParameterError
        No images, a single 2-D image not wrapped in a list, or an ambiguous array.
    """
    if isinstance(images, (str, os.PathLike)):
        path = Path(images)
        if path.is_dir():
            return list(list_images(path))
        if path.is_file():
            return [path]
        raise DataNotFoundError(f"{str(path)!r} does not exist; pass a folder of images or a list of image files.")
    if isinstance(images, np.ndarray):
        if images.ndim == 2:
            raise InvalidParameterError(
                f"got one 2-D array of shape {images.shape}; pass a list of images, e.g. [image]."
            )
        if images.ndim == 3 and images.shape[2] in (3, 4):
            raise InvalidParameterError(
                f"an array of shape {images.shape} looks like one colour image; pass a list, e.g. [image] "
                "(stacks of grey images have shape (N, H, W) with W > 4)."
            )
        if images.ndim not in (3, 4):
            raise InvalidParameterError(
                f"an image stack must have shape (N, H, W) or (N, H, W, C); got {images.shape}."
            )
        items: list = list(images)
    else:
        try:
            items = list(images)
        except TypeError as exc:
            raise InvalidParameterError(
                f"images must be a folder, a list of image paths or a list of arrays; got {type(images).__name__}."
            ) from exc
    if not items:
        raise InvalidParameterError("no images given; pass at least one image (a folder, paths or arrays).")
    return items


def iter_grey(items: Sequence, *, progress: bool = True, desc: str | None = None) -> Iterator[np.ndarray]:
    """Yield each item of :func:`as_image_list` as a grey array (see :func:`to_grey`).

    Paths are decoded straight to grey by OpenCV. A tqdm bar is shown when ``progress`` is true
    and stderr is a terminal (``disable=None``: tqdm turns itself off elsewhere, e.g. in CI logs).
    """
    bar = tqdm(items, desc=desc, unit="img", disable=None if progress else True, leave=False)
    for index, item in enumerate(bar):
        if isinstance(item, (str, os.PathLike)):
            yield read_image(item, grey=True)
        else:
            yield to_grey(item, name=f"image {index}")


def resize_grey(grey: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """Resize a grey image to ``size = (width, height)`` and return float32 in [0, 1].

    Shrinking uses ``cv2.INTER_AREA`` (pixel averaging, no aliasing); enlarging, where INTER_AREA
    degrades to nearest-neighbour, uses ``cv2.INTER_LINEAR``. An image already at ``size`` is only
    converted. uint8 images are resized before the conversion, as SeqSLAM-style pipelines do.

    Returns
    -------
    ndarray of shape (height, width), dtype float32
    """
    width, height = size
    if grey.shape != (height, width):
        shrink = width * height <= grey.shape[0] * grey.shape[1]
        grey = cv2.resize(grey, (width, height), interpolation=cv2.INTER_AREA if shrink else cv2.INTER_LINEAR)
    return as_float_grey(grey)


def as_float_grey(grey: np.ndarray) -> np.ndarray:
    """A grey image (from :func:`to_grey`) as float32 in [0, 1]: uint8 is divided by 255."""
    if grey.dtype == np.uint8:
        return grey.astype(np.float32) / np.float32(255.0)
    return grey.astype(np.float32, copy=False)
