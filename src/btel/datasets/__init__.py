"""Data sets: the synthetic route (embedded default) and loaders for real traverses and ground truth.

Queries are rows everywhere: ``queries[j]`` is query j and its true place is ``j`` for
frame-aligned traverses, or given by a :class:`GroundTruth`.
"""

from .groundtruth import GroundTruth, load_positives, save_positives
from .shards import list_shards, load_shards
from .synthetic import SyntheticRoute, synthetic_route
from .traverses import (
    DARK_THRESHOLD,
    AlignedTraverses,
    aligned_pairs,
    dark_frames,
    list_traverses,
    load_pair,
    mean_brightness,
    natural_key,
    traverse_images,
)

__all__ = [
    "DARK_THRESHOLD",
    "AlignedTraverses",
    "GroundTruth",
    "SyntheticRoute",
    "aligned_pairs",
    "dark_frames",
    "list_shards",
    "list_traverses",
    "load_pair",
    "load_positives",
    "load_shards",
    "mean_brightness",
    "natural_key",
    "save_positives",
    "synthetic_route",
    "traverse_images",
]
