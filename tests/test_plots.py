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
        r.auc_pr_vpr_bench, r.auc_pr_vpr_tutorial = pr["auc_pr_vpr_bench"], pr["auc_pr_vpr_tutorial"]
        r.recall_at_100_precision = pr["recall_at_100_precision"]
        r.pr_curve = {"precision": pr["precision"].tolist(), "recall": pr["recall"].tolist()}
        rows.append(r)
    written = plot_run(rows, tmp_path)
    path = tmp_path / "precision_recall.png"
    assert path in written and path.stat().st_size > 1000
    from btel.evaluation.plots import plot_precision_recall

    fig = plot_precision_recall(rows, tmp_path / "again.png")
    ax = fig.axes[0]
    labels = [t.get_text() for t in ax.get_legend().get_texts()]
    assert labels[0].startswith("sharp (10.0 KB): AUC-PR ") and "R@100%P" in labels[0]
    assert "(VPR-Bench)" in labels[0] and "(VPR_Tutorial)" in labels[0]
    lines = ax.get_lines()
    assert len({line.get_marker() for line in lines}) == 3  # identical curves stay distinguishable
    assert ax.get_xlabel().startswith("recall") and ax.get_ylabel() == "precision"
    # The axes span the legend's width (they were a third of it, squeezed above the long legend lines).
    rows[1].name = "bruteforce shrink whiten=shrink, a reference row with a long name"
    fig = plot_precision_recall(rows, tmp_path / "long.png")
    ax = fig.axes[0]
    fig.canvas.draw()
    legend_box, axes_box = ax.get_legend().get_window_extent(), ax.get_window_extent()
    assert legend_box.width <= fig.bbox.width and axes_box.width >= 0.75 * legend_box.width


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


# -- one style per method ----------------------------------------------------------------------------
def _line_styles(fig) -> dict[str, tuple]:
    """Legend label's method part → (colour, marker, line style, hollow) of its curve."""
    from matplotlib.colors import to_hex

    out = {}
    for line in fig.axes[0].get_lines():
        name = line.get_label().split(" (", 1)[0]
        out[name] = (to_hex(line.get_color()), line.get_marker(), line.get_linestyle(),
                     line.get_markerfacecolor() == "none")
    return out


def test_method_styles_are_fixed_per_method_and_never_repeat() -> None:
    from btel.evaluation.plots.styles import METHOD_STYLES, method_styles
    from btel.methods.registry import method_names

    names = method_names()
    assert len({(s.color, s.marker) for s in METHOD_STYLES.values()}) == len(METHOD_STYLES)
    many = ["pq shrink", "bruteforce shrink", "mine", "theirs", *names[::-1], *(f"run {i}" for i in range(30))]
    styles = method_styles(many)
    assert all(styles[n] == METHOD_STYLES[n] for n in names)  # the same whatever else the figure holds
    assert len({(s.color, s.marker) for s in styles.values()}) == len(styles)
    assert styles["pq shrink"].color == METHOD_STYLES["pq"].color  # a variant keeps its method's colour
    auto = method_styles(["lsh", "auto → lsh"])["auto → lsh"]
    lsh = METHOD_STYLES["lsh"]
    assert (auto.color, auto.marker, auto.hollow) == (lsh.color, lsh.marker, True)
    assert method_styles(["bruteforce (reference, unbudgeted)"])["bruteforce (reference, unbudgeted)"] == \
        METHOD_STYLES["bruteforce"]


def test_every_run_figure_draws_a_method_in_its_one_style_auto_visible(tmp_path: Path) -> None:
    from btel.evaluation.metrics import precision_recall
    from btel.evaluation.plots import plot_precision_recall
    from btel.evaluation.plots.run import _run_figure
    from btel.methods.registry import method_names

    rng = np.random.default_rng(1)
    n = 80
    rows = []
    for i, name in enumerate(method_names() + ["pq shrink"]):
        pred = np.clip(np.arange(n) + rng.integers(-i // 3, i // 3 + 1, n), 0, n - 1)
        r = _result(name, pred, 1000 + 10 * i)
        pr = precision_recall(rng.random(n), pred == np.arange(n))
        r.pr_curve = {"precision": pr["precision"].tolist(), "recall": pr["recall"].tolist()}
        r.recall_at_100_precision = pr["recall_at_100_precision"]
        if name == "auto":
            r.chosen_method = "lsh"
            r.predictions, r.pr_curve = rows[method_names().index("lsh")].predictions, rows[-1].pr_curve
        rows.append(r)
    assert len(rows) >= 13
    figures = [_run_figure(rows, tmp_path / "t.png", kind="tolerance", title=None),
               plot_precision_recall(rows, tmp_path / "pr.png"),
               plot_recall_vs_tolerance(rows, tmp_path / "r.png")]
    drawn = [_line_styles(fig) for fig in figures]
    assert all(d == drawn[0] for d in drawn[1:])  # one style per method across the figures
    assert len(set(drawn[0].values())) == len(rows)  # no repeats within a figure
    auto, lsh = drawn[0]["auto → lsh"], drawn[0]["lsh"]
    assert auto[:2] == lsh[:2] and auto[3] and not lsh[3]  # lsh's colour and marker, hollow


def test_precision_recall_figure_agrees_with_recall_at_full_precision(tmp_path: Path) -> None:
    from btel.evaluation.metrics import precision_recall
    from btel.evaluation.plots import plot_precision_recall

    n = 50
    correct = np.arange(n) % 3 == 0
    cases = {"tied": np.zeros(n), "graded": np.where(correct, 1.0, 0.0) + np.linspace(0, 0.5, n),
             "wrong first": np.r_[2.0, np.linspace(0, 1, n - 1)]}
    rows = []
    for name, scores in cases.items():
        pr = precision_recall(scores, correct)
        r = _result(name, np.arange(n), 500)
        r.pr_curve = {"precision": pr["precision"].tolist(), "recall": pr["recall"].tolist()}
        r.recall_at_100_precision = pr["recall_at_100_precision"]
        rows.append(r)
    fig = plot_precision_recall(rows, tmp_path / "pr.png")
    for r, line in zip(rows, fig.axes[0].get_lines()):
        x, y = np.asarray(line.get_xdata(), float), np.asarray(line.get_ydata(), float)
        at_one = x[y >= 1.0]
        assert (at_one.max() if at_one.size else 0.0) == pytest.approx(r.recall_at_100_precision)
        assert line.get_drawstyle() == "default"  # straight lines between thresholds: no invented steps
    tied = fig.axes[0].get_lines()[0]
    assert len(tied.get_xdata()) == 1 and tied.get_marker() not in (None, "", "None")  # one visible point
    assert tied.get_ydata()[0] == pytest.approx(correct.mean())


def test_the_paper_s_tree_and_its_regions_have_colours_of_their_own() -> None:
    """A demo draws BTE-C and btel-r side by side; in one colour they were told apart by marker alone."""
    from btel.evaluation.plots.styles import method_styles

    styles = method_styles(["auto → lsh", "btel-c", "btel-r", "btel-codes", "pq", "bruteforce"])
    colours = [styles[n].color for n in ("btel-c", "btel-r", "btel-codes", "pq", "bruteforce")]
    assert len(set(colours)) == len(colours)


def test_a_run_whose_rows_lie_near_zero_gets_a_recall_axis_to_fit_them(tmp_path: Path) -> None:
    """Nordland at 16 KB (recall@10 ≈ 0.05, brute force 0.47) was drawn in the bottom tenth of a 0–1 axis."""
    from btel.evaluation.plots import plot_precision_recall, plot_recall_at_k, plot_recall_vs_storage
    from btel.evaluation.plots._figure import recall_axis_top

    assert [recall_axis_top(v) for v in (0.0, 0.05, 0.09, 0.465, 0.55, 0.59, 0.6, 1.0)] == \
        [0.1, 0.1, 0.1, 0.6, 0.6, 0.7, 1.02, 1.02]
    n = 400
    near = np.arange(n)
    near[40:] = (near[40:] + 200) % n  # right within 40 frames on a tenth of the queries, wrong elsewhere
    low = _result("low", near, 10_000)
    fig = plot_recall_vs_tolerance([low], tmp_path / "tol.png")
    top = fig.axes[0].get_ylim()[1]
    assert max(low.recall_curve) < top <= max(low.recall_curve) + 0.1 and top < 0.5
    assert plot_recall_vs_storage([low], tmp_path / "storage.png", tolerance=10).axes[0].get_ylim()[1] == top
    low.recall_at_k = {1: 0.05, 5: 0.08}
    assert plot_recall_at_k([low], tmp_path / "k.png").axes[0].get_ylim()[1] == 0.1
    low.pr_curve = {"precision": [1.0, 0.5], "recall": [0.01, 0.1]}
    assert plot_precision_recall([low], tmp_path / "pr.png").axes[0].get_xlim()[1] == 0.2
    good = _result("good", np.arange(n), 10_000)  # recall 1: the whole axis, as before
    assert plot_recall_vs_tolerance([low, good], tmp_path / "both.png").axes[0].get_ylim()[1] == 1.02
