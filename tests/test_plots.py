"""Plots: PNG files with one series per method, axes as in the paper's figures."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from btel.evaluation import EvaluationResult, recall_at_tolerance, recall_curve
from btel.exceptions import InvalidParameterError
from btel.evaluation.plots import plot_recall_vs_n, plot_recall_vs_storage, plot_recall_vs_tolerance

# matplotlib's first two default colours (C0 blue, C1 orange) in OpenCV's BGR order.
_C0_BGR = (180, 119, 31)
_C1_BGR = (14, 127, 255)


def _has_colour(png: Path, bgr: tuple[int, int, int]) -> bool:
    image = cv2.imread(str(png), cv2.IMREAD_COLOR)
    assert image is not None, f"{png} is not a readable PNG"
    return bool(np.any(np.all(np.abs(image.astype(int) - bgr) <= 8, axis=2)))


def _result(name: str, predictions: np.ndarray, nbytes: int | None) -> EvaluationResult:
    return EvaluationResult(
        name=name, params={}, n_map=predictions.size, n_queries=predictions.size,
        recall=recall_at_tolerance(predictions), recall_curve=recall_curve(predictions, max_tolerance=40),
        recall_at_k=None, nbytes=nbytes, storage_breakdown=None, fit_time_s=0.1,
        query_time_s_per_query=1e-4, predictions=predictions,
    )


def _rows() -> list[EvaluationResult]:
    return [EvaluationResult.from_row(row) for row in (
        {"method": "BTE-C", "nbytes": 50_000, "n_places": 3576, "recall@0": 0.01, "recall@10": 0.02},
        {"method": "BTE-C", "nbytes": 5_000, "n_places": 64, "recall@0": 0.05, "recall@10": 0.3},
        {"method": "PQ", "nbytes": 500_000, "n_places": 1000, "recall@0": 0.3, "recall@10": 0.38},
        {"method": "PQ", "nbytes": 292_000, "n_places": 3576, "recall@0": 0.2, "recall@10": 0.24},
    )]


def test_recall_vs_tolerance_png_and_legend(tmp_path: Path) -> None:
    rng = np.random.default_rng(0)
    n = 200
    good = np.clip(np.arange(n) + rng.integers(-3, 4, size=n), 0, n - 1)
    bad = rng.integers(0, n, size=n)
    path = tmp_path / "sub" / "tol.png"
    fig = plot_recall_vs_tolerance([_result("good", good, 492_240), _result("random", bad, None)], path)
    assert path.is_file() and path.stat().st_size > 1000
    assert _has_colour(path, _C0_BGR) and _has_colour(path, _C1_BGR)
    ax = fig.axes[0]
    assert [t.get_text() for t in ax.get_legend().get_texts()] == ["good (492.2 KB)", "random"]
    assert ax.get_xlabel() == "tolerance t (frames)" and ax.get_ylabel() == "recall@t"
    line = ax.get_lines()[0]
    np.testing.assert_allclose(line.get_ydata(), recall_curve(good, max_tolerance=40))


def test_recall_vs_tolerance_from_json_dicts_and_points(tmp_path: Path) -> None:
    # Results as read back from metrics.json: string keys; one without a curve is drawn as points.
    results = [
        {"name": "a", "nbytes": 1000, "recall_curve": [0.1, 0.2, 0.4], "recall": {"0": 0.1}, "n_queries": 3,
         "status": "ok"},
        {"name": "b", "nbytes": None, "recall": {"0": 0.3, "5": 0.5, "10": 0.9}, "n_queries": 3, "status": "ok"},
    ]
    records = [EvaluationResult.from_dict(r) for r in json.loads(json.dumps(results))]
    fig = plot_recall_vs_tolerance(records, tmp_path / "p.png", max_tolerance=5)
    lines = fig.axes[0].get_lines()
    np.testing.assert_array_equal(lines[1].get_xdata(), [0, 5])
    np.testing.assert_allclose(lines[1].get_ydata(), [0.3, 0.5])
    with pytest.raises(InvalidParameterError, match="empty"):
        plot_recall_vs_tolerance([], tmp_path / "none.png")


@pytest.mark.parametrize(
    ("plot", "x_key", "xlabel"),
    [(plot_recall_vs_storage, "nbytes", "storage (bytes, log scale)"), (plot_recall_vs_n, "n_places", "N (map places)")],
)
def test_rows_plots_series_sorted_on_log_axis(tmp_path: Path, plot, x_key: str, xlabel: str) -> None:
    path = tmp_path / f"{x_key}.png"
    fig = plot(_rows(), path, tolerance=10)
    assert path.is_file() and _has_colour(path, _C0_BGR) and _has_colour(path, _C1_BGR)
    ax = fig.axes[0]
    assert ax.get_xscale() == "log" and ax.get_xlabel() == xlabel
    series = {line.get_label(): line for line in ax.get_lines()}
    assert set(series) == {"BTE-C", "PQ"}
    for method, line in series.items():
        rows = sorted((r.to_row() for r in _rows() if r.name == method), key=lambda r: r[x_key])
        np.testing.assert_array_equal(line.get_xdata(), [r[x_key] for r in rows])
        np.testing.assert_allclose(line.get_ydata(), [r["recall@10"] for r in rows])


def test_rows_errors(tmp_path: Path) -> None:
    with pytest.raises(InvalidParameterError, match=r"no recall at tolerance 5 \(available: \[0, 10\]\)"):
        plot_recall_vs_storage(_rows(), tmp_path / "x.png", tolerance=5)
    with pytest.raises(InvalidParameterError, match="has nbytes=None; a log axis"):
        plot_recall_vs_storage([EvaluationResult(name="a", recall={10: 0.1})], tmp_path / "x.png")
    with pytest.raises(InvalidParameterError, match="has n_places=0; a log axis"):
        plot_recall_vs_n([EvaluationResult(name="a", n_map=0, recall={10: 0.1})], tmp_path / "x.png")
    assert not (tmp_path / "x.png").exists()


@pytest.mark.realdata
def test_plot_real_gardenspoint_curve(gardenspoint_netvlad: tuple[np.ndarray, np.ndarray], tmp_path: Path) -> None:
    from sklearn.neighbors import NearestNeighbors

    X, Q = gardenspoint_netvlad
    pred = NearestNeighbors(n_neighbors=1).fit(X).kneighbors(Q, return_distance=False)[:, 0]
    result = _result("NetVLAD NN", pred, X.nbytes)
    path = tmp_path / "gp.png"
    fig = plot_recall_vs_tolerance([result], path)
    assert path.is_file() and _has_colour(path, _C0_BGR)
    y = fig.axes[0].get_lines()[0].get_ydata()
    assert 0 < y[0] < y[-1] <= 1  # real descriptors: imperfect at t=0, better with slack
    assert fig.axes[0].get_legend().get_texts()[0].get_text() == "NetVLAD NN (400.0 KB)"


def test_run_plots_include_precision_recall_with_auc_in_the_legend(tmp_path: Path) -> None:
    from btel.evaluation import precision_recall
    from btel.evaluation.plots import plot_run

    rng = np.random.default_rng(0)
    n = 200
    rows = []
    for name, noise in (("sharp", 0.2), ("blunt", 2.0), ("same as sharp", 0.2)):
        pred = np.clip(np.arange(n) + (rng.integers(-3, 4, size=n) if noise > 1 else 0), 0, n - 1)
        scores = -np.abs(pred - np.arange(n)) + noise * rng.standard_normal(n)
        pr = precision_recall(scores, pred == np.arange(n))
        r = _result(name, pred, 10_000)
        r.auc_pr, r.recall_at_100_precision = pr["auc_pr"], pr["recall_at_100_precision"]
        r.pr_curve = {"precision": pr["precision"].tolist(), "recall": pr["recall"].tolist()}
        rows.append(r)
    written = plot_run(rows, tmp_path)
    path = tmp_path / "precision_recall.png"
    assert path in written and path.stat().st_size > 1000
    from btel.evaluation.plots import plot_precision_recall

    fig = plot_precision_recall(rows, tmp_path / "again.png")
    ax = fig.axes[0]
    labels = [t.get_text() for t in ax.get_legend().get_texts()]
    assert labels[0].startswith("sharp (10.0 KB): AUC ") and "R@100%P" in labels[0]
    lines = ax.get_lines()
    assert len({line.get_marker() for line in lines}) == 3  # identical curves stay distinguishable
    assert ax.get_xlabel().startswith("recall") and ax.get_ylabel() == "precision"


def test_run_figure_identical_curves_integer_ticks_and_param_labels(tmp_path: Path) -> None:
    from btel.evaluation.plots import plot_run

    n = 60
    pred = np.arange(n)
    rows = [_result(name, pred, 3000) for name in ("pq", "opq", "btel-codes")]
    rows[2].settings = {"code": "random"}
    plot_run(rows, tmp_path)
    from btel.evaluation.plots.run import _run_figure

    fig = _run_figure(rows, tmp_path / "again.png", kind="tolerance", title="t")
    ax = fig.axes[0]
    labels = [t.get_text() for t in ax.get_legend().get_texts()]
    assert labels == ["pq (3.0 KB)", "opq (3.0 KB)", "btel-codes code=random (3.0 KB)"]
    ticks = ax.get_xticks()
    assert np.all(ticks == np.round(ticks))  # frames: whole numbers only
    lines = ax.get_lines()
    assert len({line.get_marker() for line in lines}) == 3
    marked = [set(np.arange(len(line.get_xdata()))[slice(*line.get_markevery()[:1], None, line.get_markevery()[1])])
              for line in lines]
    assert not (marked[0] & marked[1]) and not (marked[1] & marked[2])  # each marks its own points


def test_run_figures_name_the_rows_that_did_not_run(tmp_path: Path) -> None:
    from btel.evaluation.plots import plot_run

    pred = np.arange(30)
    missing = EvaluationResult.not_measured("itq", "does not fit", "budget too small", n_queries=30)
    import btel.evaluation.plots.run as plots

    titles: list[str] = []
    real = plots._run_figure

    def spy(results, path, *, kind, title, **kwargs):
        titles.append(title)
        return real(results, path, kind=kind, title=title, **kwargs)

    plots._run_figure = spy
    try:
        written = plot_run([_result("pq", pred, 900)], tmp_path, title="toy", not_run=[missing])
    finally:
        plots._run_figure = real
    assert written and titles == ["toy — not shown: itq (does not fit)"]
