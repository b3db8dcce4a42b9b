"""Traverses on disk: image folders, paired descriptor files and near-black frames.

A *traverses* layout is a root folder with one sub-folder per traverse (one drive along the
route, e.g. one season). File names are frame-aligned: **the same file name in two traverses is
the same place** (as in ``nordland64/{summer,winter}/images-NNNNN.png``)::

    root/
      summer/images-00010.png  images-00020.png  ...
      winter/images-00010.png  images-00020.png  ...

Descriptors built from a traverse keep its order: row i of the map matrix is place i, and
queries are rows too. Nothing is dropped silently: :func:`aligned_pairs` reports the file names
found in only one traverse, and :func:`dark_frames` returns a mask for the caller to count and
report (tunnels and the video start are near-black on Nordland).
"""

from __future__ import annotations

import logging
import os
import re
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..core.validation import check_descriptors
from ..exceptions import DataNotFoundError, DimensionMismatchError, InvalidParameterError

__all__ = [
    "IMAGE_EXTENSIONS",
    "DARK_THRESHOLD",
    "natural_key",
    "list_traverses",
    "traverse_images",
    "AlignedTraverses",
    "aligned_pairs",
    "load_pair",
    "mean_brightness",
    "dark_frames",
]

logger = logging.getLogger(__name__)

#: File suffixes read as images (compared lower-case).
IMAGE_EXTENSIONS: frozenset[str] = frozenset(
    {".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".ppm", ".pgm", ".webp"}
)

#: A frame is near-black when its mean grey level is below this fraction of full white
#: (10/255). Measured on ``nordland64`` with cv2's grey conversion: 200 summer and 96 winter
#: frames of 3,576 (the data README says ~170 and ~90); 95 of the 96 winter ones are dark in
#: summer too. There is no clean gap: 8/255 gives 187 / 65, 9/255 196 / 92, 12/255 207 / 111 and
#: 15/255 215 / 165 (dim winter frames start to count), so 10/255 is a judgement call.
DARK_THRESHOLD: float = 10.0 / 255.0

_DIGITS = re.compile(r"(\d+)")


def natural_key(name: str) -> tuple[Any, ...]:
    """Sort key that orders digit runs by value: ``img2 < img10`` (case-insensitive); names equal as numbers
    (``shard_1``, ``shard_01``) then by the name itself, so the order never depends on the file system's."""
    parts = _DIGITS.split(name)
    # Alternate (text, number) so that tuples always compare like with like; the name in a slot of its own
    # (appended to the parts, it would meet a number: `day` against `day2`).
    return tuple(int(p) if i % 2 else p.lower() for i, p in enumerate(parts)), name


def _is_image(path: Path) -> bool:
    return path.is_file() and path.suffix.lower() in IMAGE_EXTENSIONS and not path.name.startswith(".")


def _check_root(root: str | os.PathLike) -> Path:
    root = Path(root)
    if not root.is_dir():
        raise DataNotFoundError(
            f"traverses folder {str(root)!r} does not exist or is not a folder. "
            "Point to a folder holding one sub-folder of images per traverse."
        )
    return root


def list_traverses(root: str | os.PathLike) -> list[str]:
    """Names of the traverses under ``root``: its sub-folders that hold at least one image.

    Parameters
    ----------
    root : path
        Folder with one sub-folder per traverse.

    Returns
    -------
    list of str
        Sub-folder names, naturally sorted.

    Raises
    ------
    DataNotFoundError
        ``root`` is missing, or no sub-folder holds an image.
    """
    root = _check_root(root)
    names = [
        d.name
        for d in root.iterdir()
        if d.is_dir() and not d.name.startswith(".") and any(_is_image(p) for p in d.iterdir())
    ]
    if not names:
        raise DataNotFoundError(
            f"{str(root)!r} has no sub-folder with images ({', '.join(sorted(IMAGE_EXTENSIONS))}). "
            "Expected one sub-folder per traverse, e.g. root/summer/*.png and root/winter/*.png."
        )
    return sorted(names, key=natural_key)


def traverse_images(root: str | os.PathLike, name: str) -> list[Path]:
    """Image files of one traverse in route order (file names sorted naturally).

    Parameters
    ----------
    root : path
        Folder with one sub-folder per traverse.
    name : str
        The traverse (sub-folder) name.

    Returns
    -------
    list of Path
        ``images-2.png`` comes before ``images-10.png``.

    Raises
    ------
    DataNotFoundError
        The traverse folder is missing or holds no image.
    """
    root = _check_root(root)
    folder = root / name
    if not folder.is_dir():
        available = [d.name for d in root.iterdir() if d.is_dir()]
        raise DataNotFoundError(
            f"traverse {name!r} not found in {str(root)!r}; available: {sorted(available, key=natural_key)}."
        )
    files = [p for p in folder.iterdir() if _is_image(p)]
    if not files:
        raise DataNotFoundError(f"traverse folder {str(folder)!r} holds no images.")
    return sorted(files, key=lambda p: natural_key(p.name))


@dataclass(frozen=True)
class AlignedTraverses:
    """Two traverses matched by file name (same name = same place).

    Attributes
    ----------
    map_name, query_name : str
        The traverse names.
    names : list of str
        File names present in both, in route order; place i is ``names[i]``.
    map_paths, query_paths : list of Path
        ``map_paths[i]`` and ``query_paths[i]`` show place i.
    dropped_map : list of str
        File names only in the map traverse (left out).
    dropped_query : list of str
        File names only in the query traverse (left out).
    """

    map_name: str
    query_name: str
    names: list[str]
    map_paths: list[Path]
    query_paths: list[Path]
    dropped_map: list[str] = field(default_factory=list)
    dropped_query: list[str] = field(default_factory=list)

    def __len__(self) -> int:
        return len(self.names)

    @property
    def n_dropped_map(self) -> int:
        """Number of map images without a query image of the same name."""
        return len(self.dropped_map)

    @property
    def n_dropped_query(self) -> int:
        """Number of query images without a map image of the same name."""
        return len(self.dropped_query)

    def summary(self) -> str:
        """One line for logs and reports: pairs kept and images dropped from each side."""
        return (
            f"{len(self)} aligned places ({self.map_name} → map, {self.query_name} → queries); "
            f"dropped {self.n_dropped_map} map-only and {self.n_dropped_query} query-only images"
        )

    def dark_masks(self, threshold: float = DARK_THRESHOLD) -> tuple[np.ndarray, np.ndarray]:
        """Near-black masks of the aligned map and query images (see :func:`dark_frames`).

        Returns
        -------
        map_dark, query_dark : ndarray of shape (n_places,), dtype bool
        """
        return dark_frames(self.map_paths, threshold=threshold), dark_frames(self.query_paths, threshold=threshold)


def aligned_pairs(root: str | os.PathLike, map_name: str, query_name: str) -> AlignedTraverses:
    """Match two traverses by file name, keeping only places present in both.

    Images found in only one traverse are left out and listed in ``dropped_map`` /
    ``dropped_query`` (and logged as a warning), never dropped silently.

    Parameters
    ----------
    root : path
        Folder with one sub-folder per traverse.
    map_name, query_name : str
        The traverse used as the map and the one used as queries.

    Returns
    -------
    AlignedTraverses

    Raises
    ------
    DataNotFoundError
        A traverse is missing or empty, or the two share no file name.
    InvalidParameterError
        ``map_name == query_name``.
    """
    if map_name == query_name:
        raise InvalidParameterError(
            f"map and query traverse are both {map_name!r}; choose two different traverses."
        )
    map_files = {p.name: p for p in traverse_images(root, map_name)}
    query_files = {p.name: p for p in traverse_images(root, query_name)}
    common = sorted(map_files.keys() & query_files.keys(), key=natural_key)
    if not common:
        raise DataNotFoundError(
            f"traverses {map_name!r} and {query_name!r} in {str(root)!r} share no file name; "
            "frame-aligned traverses must name the same place with the same file name."
        )
    aligned = AlignedTraverses(
        map_name=map_name,
        query_name=query_name,
        names=common,
        map_paths=[map_files[n] for n in common],
        query_paths=[query_files[n] for n in common],
        dropped_map=sorted(map_files.keys() - query_files.keys(), key=natural_key),
        dropped_query=sorted(query_files.keys() - map_files.keys(), key=natural_key),
    )
    if aligned.n_dropped_map or aligned.n_dropped_query:
        logger.warning("%s", aligned.summary())
    return aligned


def _load_npy(path: str | os.PathLike, role: str) -> np.ndarray:
    from ..core.limits import check_numpy_file

    path = Path(path)
    if not path.is_file():
        raise DataNotFoundError(f"{role} file {str(path)!r} does not exist.")
    check_numpy_file(path, f"{role} file {str(path)!r}")  # numpy allocates what the header declares
    try:
        return np.load(path, allow_pickle=False)
    except ValueError as exc:
        # numpy says "Object arrays cannot be loaded when allow_pickle=False" for pickled content.
        raise DataNotFoundError(
            f"{role} file {str(path)!r} is not a plain numeric .npy array ({exc}). "
            "btel never loads pickles; save descriptors with np.save(path, X.astype(np.float32))."
        ) from exc
    except (OSError, EOFError) as exc:
        raise DataNotFoundError(f"{role} file {str(path)!r} could not be read as .npy: {exc}") from exc


def load_pair(db_path: str | os.PathLike, queries_path: str | os.PathLike) -> tuple[np.ndarray, np.ndarray]:
    """Load map and query descriptors from two ``.npy`` files (row i of the map = place i).

    Parameters
    ----------
    db_path : path
        ``.npy`` file of shape (n_places, n_features): the map.
    queries_path : path
        ``.npy`` file of shape (n_queries, n_features): one query per row.

    Returns
    -------
    db : ndarray of shape (n_places, n_features), dtype float32
    queries : ndarray of shape (n_queries, n_features), dtype float32

    Raises
    ------
    DataNotFoundError
        A file is missing, unreadable or holds pickled objects (never loaded).
    InvalidDescriptorsError
        Not 2-D, not numeric, empty, or with NaN/inf values.
    DimensionMismatchError
        The two files have different numbers of columns.
    ResourceLimitError
        A file declares more than :mod:`btel.core.limits` allows.
    """
    db = check_descriptors(_load_npy(db_path, "map descriptors"), name=f"map descriptors ({Path(db_path).name})")
    queries = _load_npy(queries_path, "query descriptors")
    qname = f"query descriptors ({Path(queries_path).name})"
    if np.ndim(queries) == 2 and queries.shape[1] != db.shape[1]:
        raise DimensionMismatchError(
            f"{qname} have {queries.shape[1]} features but the map has {db.shape[1]}. "
            "Compute both with the same extractor and settings."
        )
    return db, check_descriptors(queries, name=qname)


def _read_grey(path: str | os.PathLike) -> np.ndarray:
    """Read one image as 2-D uint8 grey (cv2's BGR→grey weights), its header checked first."""
    from ..descriptors.images import read_image  # imported here: opencv is slow to import

    if not Path(path).is_file():
        raise DataNotFoundError(f"image {str(path)!r} is missing or not a readable image file.")
    return read_image(path, grey=True)


def _brightness_of(image: Any) -> float:
    if isinstance(image, (str, os.PathLike)):
        return float(_read_grey(image).mean()) / 255.0
    arr = np.asarray(image)
    if arr.size == 0 or not (np.issubdtype(arr.dtype, np.number) or arr.dtype == bool):
        raise InvalidParameterError(
            f"an image must be a non-empty numeric array; got dtype {arr.dtype}, shape {arr.shape}."
        )
    if arr.dtype == np.uint8:
        return float(arr.mean()) / 255.0
    if np.issubdtype(arr.dtype, np.integer):
        raise InvalidParameterError(
            f"integer images must be uint8 (0–255); got {arr.dtype}. Convert to float in [0, 1] first."
        )
    return float(arr.mean())


def mean_brightness(images_or_paths: Iterable[Any] | np.ndarray) -> np.ndarray:
    """Mean grey level of each image as a fraction of full white.

    Parameters
    ----------
    images_or_paths : sequence or ndarray
        One of: a sequence of image paths (read as grey with OpenCV); a sequence of image arrays
        (uint8 in 0–255, or float in [0, 1]; colour images are averaged over all channels); a
        2-D array of shape (n_images, n_pixels), one flattened image per row (as the
        ``nordland_pixels`` test fixture); or a 3-D/4-D stack (n_images, height, width[, 3]).
        A single 2-D image must be wrapped in a list: a 2-D array means one image per row.

    Returns
    -------
    brightness : ndarray of shape (n_images,), dtype float64
        Values in [0, 1] for uint8 images and for float images in [0, 1].
    """
    if isinstance(images_or_paths, np.ndarray):
        if images_or_paths.ndim < 2:
            raise InvalidParameterError(
                f"images must be a 2-D array (one flattened image per row) or a stack of images; "
                f"got shape {images_or_paths.shape}."
            )
        arr = images_or_paths
        if arr.dtype == np.uint8:
            return arr.reshape(arr.shape[0], -1).mean(axis=1, dtype=np.float64) / 255.0
        return np.array([_brightness_of(row) for row in arr], dtype=np.float64)
    if isinstance(images_or_paths, (str, os.PathLike)):
        raise InvalidParameterError("pass a list of image paths, not a single path (wrap it in a list).")
    return np.array([_brightness_of(item) for item in images_or_paths], dtype=np.float64)


def dark_frames(
    images_or_paths: Sequence[Any] | np.ndarray, threshold: float = DARK_THRESHOLD
) -> np.ndarray:
    """Mask of near-black frames (tunnels, video start): mean grey level < ``threshold``.

    The caller counts and reports them (they stay in the data: a method that cannot localize a
    black frame should be seen failing on it).

    Parameters
    ----------
    images_or_paths : sequence or ndarray
        Images or image paths in any form :func:`mean_brightness` accepts.
    threshold : float, default 10/255
        Fraction of full white in (0, 1]; :data:`DARK_THRESHOLD` (10/255) gives 200 summer and 96
        winter frames of the 3,576 in ``nordland64``.

    Returns
    -------
    dark : ndarray of shape (n_images,), dtype bool
    """
    if isinstance(threshold, bool) or not isinstance(threshold, (int, float, np.floating, np.integer)) or not (
        0.0 < float(threshold) <= 1.0
    ):
        raise InvalidParameterError(
            f"threshold is a fraction of full white in (0, 1] (e.g. 10/255); got {threshold!r}."
        )
    return mean_brightness(images_or_paths) < float(threshold)
