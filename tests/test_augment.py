"""Augmented map views for multi-exemplar training (btel.descriptors.augment)."""

from __future__ import annotations

import numpy as np
import pytest

from btel import BTELocalizer
from btel.descriptors import augmented_views, extract_descriptors, list_images
from btel.exceptions import InvalidParameterError


def test_views_and_labels() -> None:
    rng = np.random.default_rng(0)
    images = [rng.integers(0, 256, (32, 64), dtype=np.uint8) for _ in range(3)]
    views, places = augmented_views(images, brightness=(0.5, 2.0), contrast=(0.5,), shifts=(2, 4), progress=False)
    per_image = 1 + 2 + 1 + 4
    assert len(views) == places.size == 3 * per_image
    np.testing.assert_array_equal(places, np.repeat(np.arange(3), per_image))
    original = images[0].astype(np.float32) / 255
    np.testing.assert_allclose(views[0], original)
    np.testing.assert_allclose(views[1], original * 0.5, atol=1e-6)  # darker
    assert views[2].max() <= 1.0  # brighter, clipped
    assert abs(views[3].std() - 0.5 * original.std()) < 1e-3  # lower contrast
    shifted = views[5]  # shift +2: column j comes from column j − 2
    np.testing.assert_allclose(shifted[:, 2:], original[:, :-2], atol=1e-6)


@pytest.mark.parametrize("kw", [{"brightness": (0,)}, {"contrast": (np.nan,)}, {"shifts": (0,)}, {"shifts": (1.5,)}])
def test_bad_parameters(kw) -> None:
    with pytest.raises(InvalidParameterError):
        augmented_views([np.zeros((8, 8), np.uint8)], progress=False, **kw)


@pytest.mark.realdata
def test_augmented_nordland_map_fits_with_shared_labels(nordland_dir) -> None:
    paths = list_images(nordland_dir / "summer")[:60]
    views, places = augmented_views(paths, progress=False)
    X = extract_descriptors(views, "hog", progress=False)
    assert X.shape[0] == places.size == 60 * 7
    plain = BTELocalizer(budget="8KB", progress=False, random_state=0).fit(extract_descriptors(paths, "hog", progress=False))
    model = BTELocalizer(budget="8KB", progress=False, random_state=0).fit(X, places)
    assert model.n_places_ == 60 and model.nbytes == plain.nbytes <= 8000  # bytes do not grow with views
    Q = extract_descriptors(list_images(nordland_dir / "winter")[:60], "hog", progress=False)
    pred = model.predict(Q)
    assert pred.min() >= 0 and pred.max() < 60
