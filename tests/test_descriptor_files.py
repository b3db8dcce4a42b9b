"""Saved descriptor files are untrusted input (issue 20, finding 6): their parameters are checked
against the memory limit and their PCA arrays for finite, plausible values before any image."""

from __future__ import annotations

from pathlib import Path
from typing import Any, Callable

import numpy as np
import pytest

from btel.descriptors import get_descriptor
from btel.descriptors.base import load_descriptor
from btel.exceptions import InvalidParameterError, ModelFileError, ResourceLimitError
from btel.core.modelfile import load_arrays, save_arrays


def _edited(src: Path, dst: Path, params: dict[str, Any] | None = None,
            arrays: Callable[[dict], None] | None = None) -> Path:
    loaded, header = load_arrays(src)
    header["params"].update(params or {})
    if arrays:
        arrays(loaded)
    save_arrays(dst, loaded, header)
    return dst


@pytest.fixture(scope="module")
def densevlad_file(tmp_path_factory: pytest.TempPathFactory) -> Path:
    folder = tmp_path_factory.mktemp("dv")
    rng = np.random.default_rng(0)
    images = [rng.integers(0, 255, size=(96, 128), dtype=np.uint8) for _ in range(6)]
    dv = get_descriptor("densevlad", n_clusters=4, n_components=3, max_descriptors=2000, random_state=0)
    dv.fit(images)
    return dv.save(folder / "dv.btel")


def test_hog_size_is_checked_before_any_image(tmp_path: Path) -> None:
    """size=[30000, 30000] tried 15 GiB on the first image."""
    path = get_descriptor("hog").save(tmp_path / "hog.btel")
    bad = _edited(path, tmp_path / "big.btel", {"size": [30000, 30000]})
    assert bad.stat().st_size < 2000
    with pytest.raises(ModelFileError, match="BTEL_MEMORY_LIMIT"):
        load_descriptor(bad)
    with pytest.raises(ResourceLimitError, match="HOG of size 30000×30000"):
        get_descriptor("hog", size=(30000, 30000)).transform([np.zeros((8, 8))])
    assert load_descriptor(path).output_dim == get_descriptor("hog").output_dim


def test_densevlad_pca_at_float32_max_is_refused(densevlad_file: Path, tmp_path: Path) -> None:
    """pca_components at 3e38 exited 0 and wrote NaN descriptors."""
    def huge(a: dict) -> None:
        a["pca_components"] = np.full_like(a["pca_components"], 3e38)
    with pytest.raises(ModelFileError, match="PCA components"):
        load_descriptor(_edited(densevlad_file, tmp_path / "pca.btel", arrays=huge))

    def nan_centroids(a: dict) -> None:
        a["centroids"] = np.full_like(a["centroids"], np.nan)
    with pytest.raises(ModelFileError, match="centroids contain NaN"):
        load_descriptor(_edited(densevlad_file, tmp_path / "c.btel", arrays=nan_centroids))


def test_densevlad_grid_is_counted_before_building(densevlad_file: Path, tmp_path: Path) -> None:
    """sizes=[1]*2000, step=1 took > 30 s and 2.3 GB for two images."""
    with pytest.raises(ModelFileError, match="keypoints"):
        load_descriptor(_edited(densevlad_file, tmp_path / "grid.btel", {"sizes": [1] * 2000, "step": 1}))
    with pytest.raises(ModelFileError, match="keypoints"):
        load_descriptor(_edited(densevlad_file, tmp_path / "grid2.btel", {"sizes": [1] * 2000, "step": 1,
                                                                          "max_side": 10**6}))
    # max_side=None: the image's own size is checked before its grid is built.
    model = load_descriptor(_edited(densevlad_file, tmp_path / "none.btel", {"max_side": None}))
    model.set_params(sizes=(1,) * 2000, step=1)
    with pytest.raises(ResourceLimitError, match="keypoints"):
        model.transform([np.zeros((400, 400), dtype=np.uint8)])


@pytest.mark.parametrize("params", [{"step": 1e300}, {"sizes": [[[[1]]]]}, {"n_clusters": "x"},
                                    {"step": -1}, {"unknown": 1}])
def test_odd_parameters_are_model_file_errors(densevlad_file: Path, tmp_path: Path, params: dict) -> None:
    with pytest.raises(ModelFileError):
        load_descriptor(_edited(densevlad_file, tmp_path / "odd.btel", params))


def test_legit_file_still_loads(densevlad_file: Path) -> None:
    model = load_descriptor(densevlad_file)
    assert model.output_dim == model.dim_
    with pytest.raises(InvalidParameterError):
        get_descriptor("hog", size=(0, 3)).transform([np.zeros((8, 8))])
