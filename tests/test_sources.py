"""datasets.sources: one Gardens Point loader, row names, and ground truth with its source and rule."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from btel.datasets import GroundTruth
from btel.datasets.sources import (gardens_point_path, load_gardens_point_netvlad, resolve_ground_truth,
                                   row_names, truth_description)
from btel.exceptions import DataNotFoundError, InvalidParameterError


def test_gardens_point_loader_refuses_a_missing_or_foreign_file(tmp_path: Path) -> None:
    with pytest.raises(DataNotFoundError, match="gardenspoint_netvlad"):
        load_gardens_point_netvlad(tmp_path)
    np.savez(tmp_path / "other.npz", a=np.zeros((3, 2)))
    with pytest.raises(InvalidParameterError, match="hlrTrain"):
        load_gardens_point_netvlad(tmp_path / "other.npz")
    np.savez(tmp_path / "bad.npz", hlrTrain=np.zeros((3, 2)), hlrTest=np.full((3, 2), np.nan))
    with pytest.raises(InvalidParameterError, match="finite"):
        load_gardens_point_netvlad(tmp_path / "bad.npz")
    objects = np.empty(2, dtype=object)
    np.savez(tmp_path / "pickled.npz", hlrTrain=objects, hlrTest=objects)  # never unpickled
    with pytest.raises(InvalidParameterError):
        load_gardens_point_netvlad(tmp_path / "pickled.npz")


@pytest.mark.realdata
def test_gardens_point_loader_on_the_shared_file(shared_data: Path) -> None:
    X, Q = load_gardens_point_netvlad(shared_data)
    assert X.shape == Q.shape == (200, 500) and X.dtype == Q.dtype == np.float32
    np.testing.assert_array_equal(X, load_gardens_point_netvlad(gardens_point_path(shared_data))[0])


def _named(tmp_path: Path, stem: str, east: list[float]) -> str:
    np.save(tmp_path / f"{stem}.npy", np.zeros((len(east), 4), np.float32))
    images = [[f"@{e:.2f}@4000000.00@55@H@@.jpg", None] for e in east]
    (tmp_path / f"{stem}.npy.json").write_text(json.dumps({"images": images}))
    return str(tmp_path / f"{stem}.npy")


def test_resolve_ground_truth_says_where_it_came_from_and_its_rule(tmp_path: Path) -> None:
    gt, truth = resolve_ground_truth(None, n_queries=5, n_map=5)
    assert gt is None and truth["source"].startswith("frame-aligned")
    assert truth["rule"] == "one true place per query"
    GroundTruth.from_places(np.arange(5)).save(tmp_path / "gt.npz")
    gt, truth = resolve_ground_truth(str(tmp_path / "gt.npz"), n_queries=5, n_map=5)
    assert gt.uses_tolerance and Path(truth["source"]).is_file() and Path(truth["source"]).is_absolute()
    db, q = _named(tmp_path, "db", [0, 10, 20, 30]), _named(tmp_path, "q", [1, 29])
    assert row_names(q) == ["@1.00@4000000.00@55@H@@.jpg", "@29.00@4000000.00@55@H@@.jpg"]
    gt, truth = resolve_ground_truth("utm", n_queries=2, n_map=4, db=db, queries=q)
    assert truth == {"source": "UTM in image names", "rule": "positives within 25 m"}
    assert gt.positives(0).tolist() == [0, 1, 2] and gt.positives(1).tolist() == [1, 2, 3]
    _, truth = resolve_ground_truth("utm", n_queries=2, n_map=4, db=db, queries=q, threshold=5)
    assert truth["rule"] == "positives within 5 m"
    assert truth_description(gt, "x") == {"source": "x", "rule": "positives within 25 m"}  # its radius kept


@pytest.mark.parametrize("kwargs, message", [
    ({"spec": None, "threshold": 10.0}, "threshold applies"),
    ({"spec": "utm", "threshold": 0.0}, "> 0 metres"),
    ({"spec": "utm"}, "record none"),
])
def test_resolve_ground_truth_refuses_what_cannot_hold(tmp_path: Path, kwargs: dict, message: str) -> None:
    np.save(tmp_path / "plain.npy", np.zeros((3, 4), np.float32))  # no names recorded
    plain = str(tmp_path / "plain.npy")
    with pytest.raises(InvalidParameterError, match=message):
        resolve_ground_truth(kwargs.pop("spec"), n_queries=3, n_map=3, db=plain, queries=plain, **kwargs)
