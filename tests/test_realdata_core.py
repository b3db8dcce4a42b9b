"""BTEL core on real data: Nordland (summer map, winter queries) and Gardens Point NetVLAD.

These tests check what must hold on any data — valid indices, honest storage accounting, models
that survive a save/load — and print the accuracy figures. They assert accuracy only where the
SPEC's reference figures justify it (Gardens Point, SPEC §10); on the Nordland pixel pair the
faithful method is near chance (SPEC §10), so no accuracy is asserted there.
"""

from __future__ import annotations

from pathlib import Path

import faiss
import numpy as np
import pytest

import btel
from btel import BTELocalizer
from btel.methods.btel.encoding import n_bits_for
from btel.evaluation import recall_at_tolerance
from btel.methods.btel.localizer import planned_bytes

pytestmark = pytest.mark.realdata

MAX_OVERHEAD = 4096
# Every 4th of the 3,576 frames (894 places) keeps the three fits under ~15 s on 2 cores.
NORDLAND_STEP = 4

MODELS = {
    "BTE-C": {},
    "BTE-F": {"scheme": "full"},
    "regions-10": {"n_regions": 10},
}


@pytest.fixture(scope="module")
def nordland(nordland_pixels) -> tuple[np.ndarray, np.ndarray]:
    summer, winter = nordland_pixels
    assert summer.shape == winter.shape == (3576, 2048)
    return summer[::NORDLAND_STEP], winter[::NORDLAND_STEP]


@pytest.mark.parametrize("name", list(MODELS))
def test_nordland_summer_to_winter(nordland, name: str, tmp_path: Path) -> None:
    summer, winter = nordland
    n, d = summer.shape
    params = MODELS[name]
    model = BTELocalizer(progress=False, n_jobs=2, random_state=0, **params).fit(summer)
    pred = model.predict(winter)
    recall = recall_at_tolerance(pred, tolerances=[0, 5, 10])
    print(f"\nNordland pixels {name}: N = {n}, d' = {model.n_selected_}, r = {model.n_regions_}, "
          f"{model.nbytes} B, fit {model.fit_time_:.1f} s, unconverged {model.n_unconverged_}, recall {recall}")
    assert pred.dtype == np.int64 and pred.shape == (n,)
    assert np.all((pred >= 0) & (pred < n))
    scheme = params.get("scheme", "compressed")
    assert model.nbytes == planned_bytes(int(sum(model.region_sizes_)), d, n_selected=model.n_selected_,
                                         region_sizes=list(model.region_sizes_), scheme=scheme)
    if name == "regions-10":
        assert model.n_regions_ == 10 and np.all(model.region_sizes_ >= 2)
        region = model.predict_region(winter)
        assert np.all(pred >= model.region_starts_[region])
        assert np.all(pred < model.region_starts_[region] + model.region_sizes_[region])
    path = model.save(tmp_path / f"{name}.npz")
    assert 0 <= path.stat().st_size - model.nbytes <= MAX_OVERHEAD
    loaded = btel.load(path)
    np.testing.assert_array_equal(loaded.predict(winter), pred)
    np.testing.assert_array_equal(loaded.decision_function(winter), model.decision_function(winter))


def test_nordland_full_scheme_storage_is_linear_compressed_logarithmic(nordland) -> None:
    summer, _ = nordland
    n, d = summer.shape
    d_sel = round(0.1 * d)
    compressed = planned_bytes(n, d, n_selected=d_sel)
    full = planned_bytes(n, d, n_selected=d_sel, scheme="full")
    # N − 1 node classifiers against ceil(log2 N) bit classifiers, of the same size each.
    assert full * n_bits_for(n) == compressed * (n - 1)


def test_gardens_point_netvlad(gardenspoint_netvlad) -> None:
    M, Q = gardenspoint_netvlad
    assert M.shape == Q.shape == (200, 500)
    index = faiss.IndexFlatL2(M.shape[1])
    index.add(M)
    brute = index.search(Q, 1)[1][:, 0]
    brute_recall = recall_at_tolerance(brute, tolerances=[0, 2, 5])
    results = {}
    for label, params in {"BTE-C c=0.1": {}, "BTE-C c=1": {"feature_ratio": 1.0}}.items():
        model = BTELocalizer(progress=False, random_state=0, **params).fit(M)
        pred = model.predict(Q)
        assert np.all((pred >= 0) & (pred < 200))
        results[label] = (recall_at_tolerance(pred, tolerances=[0, 2, 5]), model.nbytes)
    print(f"\nGardens Point NetVLAD: brute force recall {brute_recall}")
    for label, (recall, nbytes) in results.items():
        print(f"Gardens Point NetVLAD: {label} recall {recall}, {nbytes} B")
    # Chance at tolerance 5 over 200 places is 11/200 = 0.055; SPEC §10 reports 0.28 (brute 0.37).
    for label, (recall, _) in results.items():
        assert recall[5] > 0.15, label
    assert brute_recall[5] > 0.3
