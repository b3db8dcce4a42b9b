"""Data sets: the synthetic route (embedded default) and loaders for real traverses and ground truth.

Queries are rows everywhere: ``queries[j]`` is query j and its true place is ``j`` for
frame-aligned traverses, or given by a :class:`GroundTruth`.
"""

from typing import TYPE_CHECKING

from .._lazy import lazy_names

if TYPE_CHECKING:  # pragma: no cover - imported on first use (btel._lazy)
    from .groundtruth import GroundTruth, load_positives, save_positives
    from .nordland import NordlandData
    from .sources import load_gardens_point_netvlad, resolve_ground_truth
    from .shards import list_shards, load_shards
    from .synthetic import SyntheticRoute, synthetic_route
    from .traverses import (DARK_THRESHOLD, AlignedTraverses, aligned_pairs, dark_frames, list_traverses,
                            load_pair, mean_brightness, natural_key, traverse_images)

__all__ = [
    "DARK_THRESHOLD",
    "AlignedTraverses",
    "GroundTruth",
    "NordlandData",
    "SyntheticRoute",
    "aligned_pairs",
    "dark_frames",
    "list_shards",
    "list_traverses",
    "load_gardens_point_netvlad",
    "load_pair",
    "load_positives",
    "load_shards",
    "mean_brightness",
    "natural_key",
    "resolve_ground_truth",
    "save_positives",
    "synthetic_route",
    "traverse_images",
]

__getattr__, __dir__ = lazy_names(__name__, {
    **dict.fromkeys(("GroundTruth", "load_positives", "save_positives"), ".groundtruth"),
    **dict.fromkeys(("list_shards", "load_shards"), ".shards"),
    **dict.fromkeys(("SyntheticRoute", "synthetic_route"), ".synthetic"),
    "NordlandData": ".nordland",
    **dict.fromkeys(("load_gardens_point_netvlad", "resolve_ground_truth"), ".sources"),
    **{name: ".traverses" for name in __all__ if name not in
       ("GroundTruth", "load_positives", "save_positives", "list_shards", "load_shards", "SyntheticRoute",
        "synthetic_route", "NordlandData", "load_gardens_point_netvlad", "resolve_ground_truth")}})
