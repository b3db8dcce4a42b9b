"""Reading images and turning every accepted image form into one grey array.

An *image* given to a descriptor is either a path to a file OpenCV can decode or an ndarray:
grey ``(H, W)``, grey ``(H, W, 1)``, colour ``(H, W, 3)`` in **RGB** order, or ``(H, W, 4)`` RGBA.
Pixel values are ``uint8`` (0..255), ``uint16`` (0..65535), ``bool``, other integers in 0..255,
or floats in [0, 1] (the scikit-image convention). A collection of images is a list (or any
iterable) of those, a folder (every image in it, see :func:`list_images`), or an array stacked
along its first axis ``(N, H, W)`` / ``(N, H, W, C)``.

Internally every image becomes a 2-D grey array that is either ``uint8`` or ``float32`` in
[0, 1]; each descriptor then converts to what its library needs.

Image files are untrusted input: :func:`read_image` reads a file's header with Pillow first
(PNG, JPEG, BMP, TIFF, PNM and WebP only), checks the memory its decoding needs against
:mod:`btel.core.limits` (:func:`decode_bytes`) and, for PNG, that every chunk lies inside the file with
its checksum, and only then lets OpenCV decode it. OpenCV's own pixel cap
(``OPENCV_IO_MAX_IMAGE_PIXELS``) is set from the same limit when btel loads OpenCV.
"""

from __future__ import annotations

import io
import os
import re
import sys
from pathlib import Path
from typing import Any, Iterator, Sequence

import numpy as np
from tqdm.auto import tqdm

from ..exceptions import DataNotFoundError, InvalidParameterError, ResourceLimitError
from ..core.limits import check_bytes, format_size, memory_limit

#: OpenCV's environment variable for its decoders' pixel cap, read once when OpenCV loads.
OPENCV_PIXEL_CAP = "OPENCV_IO_MAX_IMAGE_PIXELS"


def _cap_opencv_pixels() -> None:
    """Set OpenCV's pixel cap from btel's memory limit (at least 2 bytes per decoded pixel) unless
    OpenCV is loaded already or the user set the cap: a backstop behind :func:`read_image`'s check.
    A cap the user set must be a whole number: OpenCV parses it with ``std::stoull`` and aborts the process."""
    given = os.environ.get(OPENCV_PIXEL_CAP)
    if "cv2" in sys.modules or (given is not None and given.strip().isascii() and given.strip().isdigit()):
        return
    if given is not None:
        raise InvalidParameterError(f"{OPENCV_PIXEL_CAP}={given[:40]!r} is not a whole number of pixels, and OpenCV "
                                    "aborts on it; give a number or unset it (btel then sets it from BTEL_MEMORY_LIMIT).")
    try:
        os.environ[OPENCV_PIXEL_CAP] = str(max(1, memory_limit() // 2))
    except InvalidParameterError:  # a malformed BTEL_MEMORY_LIMIT is reported where the limit is used
        pass


_cap_opencv_pixels()
import cv2  # noqa: E402 - after its pixel cap is set

__all__ = ["IMAGE_EXTENSIONS", "DECODED_FORMATS", "decode_bytes", "image_header", "ImageInput", "list_images",
           "not_images", "read_image", "to_grey", "as_image_list", "iter_grey", "resize_grey"]

#: File name endings :func:`list_images` picks up (compared case-insensitively).
IMAGE_EXTENSIONS: tuple[str, ...] = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".ppm", ".pgm", ".webp")

#: What descriptors accept as "images": a folder, or a sequence of paths / ndarrays.
ImageInput = Any

#: Image formats :func:`read_image` decodes (Pillow's names): those whose header Pillow reads.
DECODED_FORMATS: tuple[str, ...] = ("PNG", "JPEG", "BMP", "TIFF", "PPM", "WEBP")
#: Most start-of-scan markers (0xFFDA) a JPEG may hold: ten times libjpeg's progressive script (10 scans, 6 grey).
#: Each scan is a decoder pass over every block: 20,000 empty scans in 200 KB took minutes to decode.
MAX_JPEG_SCANS = 100


def _natural_key(path: Path) -> tuple:
    # "2.jpg" before "10.jpg": digit runs compare as numbers. re.split with a capture group puts
    # text at even and numbers at odd positions, so equal positions always hold equal types.
    # The name breaks ties (img1, img01) in a slot of its own: appended to the parts it would meet a
    # number (img against img2).
    parts = re.split(r"(\d+)", path.name.lower())
    return tuple(int(p) if i % 2 else p for i, p in enumerate(parts)), path.name


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


def not_images(folder: str | os.PathLike) -> list[str]:
    """Names of what :func:`list_images` leaves out of ``folder`` (other files, sub-folders; hidden
    entries aside), sorted: what a user may have expected to be read. An image's name on what is no regular
    file (a FIFO, a device, a broken or looping link) says so."""
    return sorted(p.name + ("/" if p.is_dir() else " (not a regular file)" if p.suffix.lower() in IMAGE_EXTENSIONS
                            else "") for p in Path(folder).iterdir()
                  if not p.name.startswith(".") and not (p.is_file() and p.suffix.lower() in IMAGE_EXTENSIONS))


def decode_bytes(width: int, height: int, channels: int, *, grey: bool, sample_bytes: int = 1,
                 tiff: bool = False) -> int:
    """Memory that decoding a ``width × height`` image may take, in bytes, from its header.

    Per pixel: ``2 ×`` the output channels (the decoded image and one converted copy; 1 channel
    when ``grey``, else 3), plus the decoder's own full-size buffers — 2 bytes per sample of the
    file (``channels × sample_bytes``: a progressive JPEG's coefficients, WebP's frame), and for
    a TIFF a whole strip read raw and unpacked to 4 channels, 4 bytes per sample plus 2. The
    measurements behind it are on ``docs/decisions/reader-bounds.md``.
    """
    samples = int(channels) * int(sample_bytes)
    per_pixel = 2 * (1 if grey else 3) + (4 * samples + 2 if tiff else 2 * samples)
    return int(width) * int(height) * per_pixel


def image_header(data: bytes) -> dict[str, Any]:
    """What Pillow reads from an image file's header without decoding it.

    Returns ``{"format", "width", "height", "tile", "channels", "sample_bytes", "animated", "image"}``
    (``image`` is Pillow's lazily opened image; ``tile`` a TIFF's tile size, decoded whole, else (0, 0)). Raises what Pillow raises (see
    :func:`_check_header`), including ``DecompressionBombWarning`` past ``Image.MAX_IMAGE_PIXELS``
    when warnings are errors.
    """
    from PIL import Image

    image = Image.open(io.BytesIO(data), formats=DECODED_FORMATS)
    bits = image.tag_v2.get(258) if image.format == "TIFF" else None  # BitsPerSample
    if bits is not None:
        sample_bytes = max(1, -(-max(bits if isinstance(bits, tuple) else (bits,)) // 8))
    else:
        sample_bytes = 2 if image.mode.startswith("I;16") else 4 if image.mode in ("I", "F") else 1
    tile = (int(image.tag_v2.get(322, 0)), int(image.tag_v2.get(323, 0))) if image.format == "TIFF" else (0, 0)
    return {"format": image.format, "width": image.size[0], "height": image.size[1], "tile": tile,
            "channels": len(image.getbands()), "sample_bytes": int(sample_bytes),
            "animated": bool(getattr(image, "is_animated", False)), "image": image}


def _check_header(data: bytes, path: Path, grey: bool) -> int:
    """Read the image header in ``data`` with Pillow and check it before anything is decoded.

    Returns the image's pixel count. Raises :class:`DataNotFoundError` for a format outside
    :data:`DECODED_FORMATS`, a damaged header, an animated image, or (PNG) a chunk that runs past
    the end of the file or fails its checksum; :class:`ResourceLimitError` when decoding would
    exceed the memory limit (:func:`decode_bytes`).
    """
    import warnings

    from PIL import Image, UnidentifiedImageError

    name = str(path)
    cap = max(1, memory_limit() // decode_bytes(1, 1, 1, grey=grey))  # the least any image costs per pixel
    before = Image.MAX_IMAGE_PIXELS
    Image.MAX_IMAGE_PIXELS = cap  # Pillow refuses past 2 × cap while opening; the warning below cap is ours
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # Pillow's notes on odd tags: the checks below decide
            warnings.simplefilter("error", Image.DecompressionBombWarning)
            header = image_header(data)
            width, height, channels = header["width"], header["height"], header["channels"]
            if header["format"] in ("PNG", "WEBP") and header["animated"]:
                raise DataNotFoundError(f"{name!r} is an animated {header['format']}; btel reads still "
                                        "images. Give its frames as separate files.")
            tile_w, tile_h = header["tile"]
            size = f"{width}×{height}" + (f" in {tile_w}×{tile_h} tiles" if tile_w or tile_h else "")
            check_bytes(decode_bytes(max(width, tile_w), max(height, tile_h), channels, grey=grey,
                                     sample_bytes=header["sample_bytes"], tiff=header["format"] == "TIFF"),
                        f"image {name!r} ({size}, {channels} channel{'s' * (channels > 1)}, decoded)")
            # Scan data stuff each 0xFF byte (0xFF00): only markers count (metadata bytes rarely). One pass, in memory.
            if header["format"] == "JPEG" and (scans := data.count(b"\xff\xda")) > MAX_JPEG_SCANS:
                raise DataNotFoundError(f"{name!r} is a JPEG of {scans} scans, more than the {MAX_JPEG_SCANS} btel "
                                        "decodes (a camera writes 1 to 10). Re-save it as a PNG or a baseline JPEG.")
            if header["format"] == "PNG":
                header["image"].verify()  # every chunk inside the file, with a good checksum, up to IEND
    except (Image.DecompressionBombError, Image.DecompressionBombWarning) as exc:
        raise ResourceLimitError(
            f"image {name!r} has more pixels than btel's memory limit of {format_size(memory_limit())} can "
            f"decode (Pillow: {str(exc)[:120]}); if the input is genuine, raise the limit with "
            "BTEL_MEMORY_LIMIT (e.g. BTEL_MEMORY_LIMIT=4G).") from None
    except UnidentifiedImageError:
        raise DataNotFoundError(
            f"OpenCV cannot decode {name!r}: it is not a {', '.join(DECODED_FORMATS[:-1])} or "
            f"{DECODED_FORMATS[-1]} image (btel reads those formats only). Convert it to PNG or remove "
            "it.") from None
    except (DataNotFoundError, ResourceLimitError):
        raise
    except Exception as exc:  # Pillow's parsers raise SyntaxError, OSError, ValueError, struct.error…
        raise DataNotFoundError(
            f"OpenCV cannot decode {name!r}: its header or chunks are damaged ({type(exc).__name__}: "
            f"{str(exc)[:120]}). Remove or replace that file.") from None
    finally:
        Image.MAX_IMAGE_PIXELS = before
    return width * height


def read_image(path: str | os.PathLike, *, grey: bool = False) -> np.ndarray:
    """Decode one image file with OpenCV, after checking its header (see the module docstring).

    Parameters
    ----------
    path : str or path-like
        A PNG, JPEG, BMP, TIFF, PNM (PPM/PGM/PBM) or WebP file. 16-bit files are reduced to 8
        bits by OpenCV; a multi-page TIFF gives its first page; animated PNGs are refused.
    grey : bool
        Decode straight to grey (OpenCV's luminance conversion) instead of colour.

    Returns
    -------
    image : ndarray of dtype uint8
        Shape ``(H, W)`` when ``grey``, else ``(H, W, 3)`` in RGB order.

    Raises
    ------
    DataNotFoundError
        The file does not exist, is empty, is not in one of those formats, or its header or data
        are damaged (the message names the file).
    ResourceLimitError
        The file, or the memory its header says decoding needs (:func:`decode_bytes`), exceeds
        :mod:`btel.core.limits` (raise ``BTEL_MEMORY_LIMIT`` for genuinely large images).
    """
    from ..core.limits import read_regular

    path = Path(path)
    if not path.exists():
        raise DataNotFoundError(f"image file {str(path)!r} does not exist.")
    if not path.is_file():
        raise DataNotFoundError(f"{str(path)!r} is a folder, not an image file.")
    # Read the bytes once (np.frombuffer + imdecode rather than cv2.imread: imread cannot open
    # non-ASCII paths on Windows and gives no reason when it fails).
    raw = read_regular(path, f"image file {str(path)!r}")
    if not raw:
        raise DataNotFoundError(f"image file {str(path)!r} is empty (0 bytes). Remove or replace it.")
    pixels = _check_header(raw, path, grey)
    flags = cv2.IMREAD_GRAYSCALE if grey else cv2.IMREAD_COLOR
    level = cv2.utils.logging.getLogLevel()
    cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_SILENT)  # the error below says it in one line
    try:
        image = cv2.imdecode(np.frombuffer(raw, dtype=np.uint8), flags)
    except cv2.error:
        image = None
    finally:
        cv2.utils.logging.setLogLevel(level)
    if image is None:
        cap = os.environ.get(OPENCV_PIXEL_CAP, "")
        over_cap = cap.isdigit() and pixels > int(cap)
        raise DataNotFoundError(
            f"OpenCV cannot decode {str(path)!r} as an image (corrupt, truncated or unsupported "
            "format). Remove or replace that file." if not over_cap else
            f"OpenCV refused {str(path)!r}: its {pixels} pixels exceed {OPENCV_PIXEL_CAP}={cap} (yours, or set from "
            "BTEL_MEMORY_LIMIT when OpenCV was loaded); raise it before starting Python for larger images.")
    if image.shape[0] * image.shape[1] != pixels:  # the header Pillow read is not the image OpenCV decoded
        raise DataNotFoundError(f"{str(path)!r}: the image data do not match its header "
                                f"({image.shape[1]}×{image.shape[0]} decoded, {pixels} pixels declared).")
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
