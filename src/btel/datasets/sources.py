"""Where a run's data and ground truth come from, loaded once each and described in the run's words.

- :func:`load_gardens_point_netvlad`: the Gardens Point NetVLAD descriptors (day map, night
  queries, frame-aligned), the one loader every experiment, test and benchmark reads them with.
- :func:`row_names`: the image name of every row of a descriptor file (``btel extract``'s ``.json``
  sidecar, or an hloc ``.h5``).
- :func:`resolve_ground_truth`: a ground-truth spec (None = frame-aligned, a file, or ``"utm"``:
  positions in the image names) turned into a :class:`~btel.datasets.GroundTruth` and a
  description — its source (a path that exists, or "UTM in image names") and its positive rule
  (e.g. "positives within 25 m") — that a run folder records beside every row.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np

from ..exceptions import DataNotFoundError, InvalidParameterError
from .row_names import row_names  # noqa: F401 (re-exported)

__all__ = ["GARDENS_POINT_NETVLAD", "gardens_point_path", "load_gardens_point_netvlad", "row_names",
           "resolve_ground_truth", "truth_description"]

#: The Gardens Point NetVLAD file, relative to the shared data folder.
GARDENS_POINT_NETVLAD = Path("gardenspoint_netvlad") / "hiddenRepr-GardensPoint.npz"


def gardens_point_path(data_root: str | os.PathLike) -> Path:
    """``data_root/gardenspoint_netvlad/hiddenRepr-GardensPoint.npz`` (it may not exist)."""
    return Path(data_root) / GARDENS_POINT_NETVLAD


def load_gardens_point_netvlad(path: str | os.PathLike) -> tuple[np.ndarray, np.ndarray]:
    """The Gardens Point NetVLAD descriptors: (day map, night queries), frame-aligned.

    Parameters
    ----------
    path : path
        The ``.npz`` file (arrays ``hlrTrain`` and ``hlrTest``), or a data folder holding
        :data:`GARDENS_POINT_NETVLAD`.

    Returns
    -------
    X : ndarray of shape (n_places, n_features), dtype float32
        Day traverse (the map), row i = place i.
    Q : ndarray of shape (n_places, n_features), dtype float32
        Night traverse (the queries), row j taken at place j.

    Raises
    ------
    DataNotFoundError
        No such file.
    InvalidParameterError
        The file lacks either array, or they are not two finite matrices of one shape.
    """
    path = Path(path)
    if path.is_dir():
        path = path / GARDENS_POINT_NETVLAD
    if not path.is_file():
        raise DataNotFoundError(f"Gardens Point NetVLAD file {str(path)!r} not found; give the shared data "
                                "folder holding gardenspoint_netvlad/hiddenRepr-GardensPoint.npz.")
    try:
        with np.load(path, allow_pickle=False) as z:
            X, Q = np.asarray(z["hlrTrain"], np.float32), np.asarray(z["hlrTest"], np.float32)
    except (KeyError, ValueError, OSError) as exc:
        raise InvalidParameterError(f"{path}: not the Gardens Point NetVLAD file (arrays hlrTrain and "
                                    f"hlrTest expected; {type(exc).__name__}: {exc}).") from None
    if X.ndim != 2 or X.shape != Q.shape or not (np.isfinite(X).all() and np.isfinite(Q).all()):
        raise InvalidParameterError(f"{path}: hlrTrain {X.shape} and hlrTest {Q.shape} must be two finite "
                                    "matrices of one shape (frame-aligned day and night traverses).")
    return X, Q


def truth_description(gt: Any, source: str, rule: str | None = None) -> dict[str, str]:
    """``{"source", "rule"}`` of a ground truth: where it came from and which places count as correct."""
    radius = getattr(gt, "radius", None)  # positions: the positives are those within a distance
    if rule is None and radius is not None:
        rule = f"positives within {radius:g} m"
    if rule is None:
        rule = "one true place per query" if gt is None or gt.uses_tolerance else "positives listed per query"
    return {"source": source, "rule": rule}


def resolve_ground_truth(spec: str | None, *, n_queries: int, n_map: int, db: str | None = None,
                         queries: str | None = None,
                         threshold: float | None = None) -> tuple[Any, dict[str, str]]:
    """A ground-truth spec as a :class:`~btel.datasets.GroundTruth` (None: frame-aligned) and its description.

    Parameters
    ----------
    spec : str or None
        None: frame-aligned (query j is place j). ``"utm"``: positives within ``threshold`` metres
        (default 25, VPR-methods-evaluation's), from the UTM positions in the image names of ``db``
        and ``queries`` (:func:`row_names`). Else a file :meth:`GroundTruth.from_file` reads.
    n_queries, n_map : int
        The counts the ground truth must match.
    db, queries : str, optional
        The descriptor files (needed for ``"utm"``).
    threshold : float, optional
        Metres, with ``"utm"`` only.

    Returns
    -------
    ground_truth : GroundTruth or None
    description : dict
        ``{"source": ..., "rule": ...}``: a file's absolute path, "UTM in image names" or
        "frame-aligned"; the positive rule.

    Raises
    ------
    InvalidParameterError
        A threshold without ``"utm"``, a threshold ≤ 0, names missing or not one per row, or a
        file whose counts do not match.
    """
    from .groundtruth import GroundTruth
    from .groundtruth_files import check_some_positive
    from .vpr_names import DEFAULT_POSITIVE_DIST_THRESHOLD, utm_of_names

    if threshold is not None and spec != "utm":
        raise InvalidParameterError("a positive distance threshold applies to the UTM ground truth "
                                    "(positions in the image names); a ground-truth file says its own "
                                    "positives.")
    if spec is None:
        return None, truth_description(None, "frame-aligned (query j is place j)")
    if spec != "utm":
        gt = GroundTruth.from_file(spec, n_queries=n_queries, n_map=n_map)
        rule = None if gt.radius is None else f"positives within {gt.radius:g} m (posDistThr of the file)"
        return gt, truth_description(gt, str(Path(spec).resolve()), rule)
    threshold = DEFAULT_POSITIVE_DIST_THRESHOLD if threshold is None else float(threshold)
    if not threshold > 0:
        raise InvalidParameterError(f"the positive distance threshold must be > 0 metres; got {threshold:g}.")
    utm = {}
    for what, path, n in (("map", db, n_map), ("queries", queries, n_queries)):
        found = None if path is None else row_names(path)
        if found is None:
            raise InvalidParameterError(
                f"the UTM ground truth reads positions from image names, and the {what} descriptors {path} "
                "record none; give descriptors written by `btel extract` (the names are in the .json beside "
                "them) or an hloc .h5.")
        if len(found) != n:
            raise InvalidParameterError(f"{path}: {len(found)} image names recorded for {n} rows; the file "
                                        "and its .json no longer match (re-run btel extract).")
        utm[what] = utm_of_names(found, f"{what} {path}")
    gt = GroundTruth.from_utm(utm["map"], utm["queries"], threshold)
    check_some_positive(gt, f"the UTM ground truth (positives within {threshold:g} m of the image names' positions)")
    return gt, truth_description(gt, "UTM in image names", f"positives within {threshold:g} m")
