"""Every baseline on real Nordland frames (summer = map, winter = queries, frame-aligned).

Recall figures are printed (``pytest -s``), not asserted against tuned values; the only recall
assertion is one the data clearly supports (better than chance). The SPEC §10 PQ reference on HOG
is in test_baselines_spec_reference.py.
"""

from __future__ import annotations

import numpy as np
import pytest

from btel.methods.baselines import BASELINES
from btel.core.storage import parse_budget

pytestmark = pytest.mark.realdata

HEIGHT, WIDTH = 32, 64


def patch_normalise_rows(pixels: np.ndarray, patch: int = 8) -> np.ndarray:
    """SeqSLAM's front end on flattened 32×64 thumbnails: each 8×8 patch to zero mean, unit std."""
    p = pixels.reshape(len(pixels), HEIGHT // patch, patch, WIDTH // patch, patch).astype(np.float64)
    mean = p.mean(axis=(2, 4), keepdims=True)
    std = p.std(axis=(2, 4), keepdims=True)
    out = np.divide(p - mean, std, out=np.zeros_like(p), where=std > 1e-6)
    return out.reshape(len(pixels), -1).astype(np.float32)


def recall(pred: np.ndarray, tolerance: int) -> float:
    return float(np.mean(np.abs(pred - np.arange(len(pred))) <= tolerance))


@pytest.fixture(scope="module")
def subset(nordland_pixels) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Every 4th frame (894 places): raw grey pixels and their patch-normalised version."""
    summer, winter = nordland_pixels[0][::4], nordland_pixels[1][::4]
    return {
        "pixels": (summer, winter),
        "patchnorm": (patch_normalise_rows(summer), patch_normalise_rows(winter)),
    }


CASES = [
    # name, budget, input; brute force and SeqSLAM have one size each (7.3 MB and 1.83 MB here).
    ("bruteforce", None, "pixels"),
    ("pq", "500KB", "pixels"),
    ("opq", "500KB", "pixels"),
    ("itq", "500KB", "pixels"),
    ("seqslam", "2MB", "patchnorm"),
]


@pytest.mark.parametrize("name, budget, features", CASES)
def test_baseline_localises_winter_against_summer(name, budget, features, subset):
    summer, winter = subset[features]
    n = len(winter)
    model = BASELINES[name](budget=budget, n_jobs=1).fit(summer)
    pred = model.predict(winter)
    ranked = model.rank(winter, 10)
    assert pred.shape == (n,) and pred.dtype == np.int64
    assert pred.min() >= 0 and pred.max() < n
    assert ranked.shape == (n, 10) and np.array_equal(ranked[:, 0], pred)
    if budget is not None:
        assert model.nbytes <= parse_budget(budget)
    r0, r10 = recall(pred, 0), recall(pred, 10)
    chance10 = 21 / n
    print(f"\n{name} on {features}, N = {n}: {model.nbytes} B, recall@0 = {r0:.3f}, recall@10 = {r10:.3f} "
          f"(chance {chance10:.3f})")
    if name in ("bruteforce", "seqslam"):
        # Summer and winter frames of one place share structure that both exploit (SPEC §10:
        # brute force on HOG gets 0.38; SeqSLAM is built for exactly this pair).
        assert r10 > 2 * chance10
