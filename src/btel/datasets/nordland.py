"""The Nordland data set (``nordland64/{summer,winter}``): frame-aligned seasons, described once.

:class:`NordlandData` is the one loader of Nordland in btel: the experiments and the benchmarks
read its descriptors (HOG, patch-normalised thumbnails, …) through it, each season extracted once
into a cache folder (``nordland64-<season>-<descriptor>[-firstN].npy``).
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..exceptions import DataNotFoundError

__all__ = ["SEASONS", "QUICK_FRAMES", "NordlandData", "default_nordland_root"]

SEASONS = ("summer", "winter")
#: Frames per season read in quick mode.
QUICK_FRAMES = 300


#: Environment variable naming the shared data folder (the one holding ``nordland64/``), as the tests read it.
ENV_SHARED_DATA = "BTEL_SHARED_DATA"


def default_nordland_root() -> Path:
    """``$BTEL_SHARED_DATA/nordland64``, else ``../shared/data/nordland64`` from the working directory (the
    layout CI and developers use)."""
    shared = os.environ.get(ENV_SHARED_DATA)
    return (Path(shared) if shared else Path("..") / "shared" / "data") / "nordland64"


@dataclass
class NordlandData:
    """Cached HOG and thumbnail descriptors of both Nordland seasons.

    Parameters
    ----------
    root : path
        Folder holding ``summer/`` and ``winter/`` (frame-aligned file names).
    cache_dir : path
        Where extracted descriptors are kept (``nordland64-<season>-<descriptor>.npy``).
    """

    root: Path
    cache_dir: Path
    progress: bool = True
    #: Only the first ``max_frames`` frames of each season are read (quick mode); None = all.
    max_frames: int | None = None
    #: Front-end parameters given to every method (e.g. ``{"delta": 10}``); None: each method's default.
    front_end: dict[str, Any] | None = None
    _features: dict[tuple[str, str], np.ndarray] = field(default_factory=dict, repr=False)

    def __post_init__(self) -> None:
        self.root = Path(self.root)
        self.cache_dir = Path(self.cache_dir)
        if not self.root.is_dir():
            raise DataNotFoundError(
                f"Nordland folder {str(self.root)!r} does not exist (relative paths start at {str(Path.cwd())!r}). "
                f"Run from the project's root (beside ../shared), set {ENV_SHARED_DATA} to the folder holding "
                "nordland64/, or pass --data pointing at a folder with summer/ and winter/ images.")
        missing = [s for s in SEASONS if not (self.root / s).is_dir()]
        if missing:
            raise DataNotFoundError(
                f"Nordland folder {str(self.root)!r} lacks {', '.join(missing)}/; pass --data pointing at a "
                "folder with summer/ and winter/ frame-aligned images (e.g. ../shared/data/nordland64)."
            )

    def features(self, season: str, descriptor: str) -> np.ndarray:
        """Descriptors of every frame of ``season`` (rows in file-name order), extracted once."""
        from ..descriptors.extract import extract_cached
        from ..descriptors.images import list_images

        key = (season, descriptor)
        if key not in self._features:
            paths = list_images(self.root / season)[: self.max_frames]
            suffix = "" if self.max_frames is None else f"-first{self.max_frames}"
            out = self.cache_dir / f"nordland64-{season}-{descriptor}{suffix}.npy"
            X, _ = extract_cached(paths, out, descriptor, progress=self.progress)
            self._features[key] = X
        return self._features[key]

    def pair(self, descriptor: str, map_season: str = "summer",
             n_places: int | None = None) -> tuple[np.ndarray, np.ndarray]:
        """(map, queries) described by ``descriptor``: the first ``n_places`` frames of both seasons."""
        query_season = SEASONS[1 - SEASONS.index(map_season)]
        X = self.features(map_season, descriptor)
        Q = self.features(query_season, descriptor)
        n = X.shape[0] if n_places is None else min(n_places, X.shape[0])
        return X[:n], Q[:n]
