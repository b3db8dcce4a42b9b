"""Experiment "frontier": every method × budgets on routes and on independent places, and auto's choice.

``btel experiment frontier`` measures, in one run, the key recall of every registered method (plus
asymmetric / Hamming LSH, LSH with i.i.d. Gaussian hyperplanes beside its default structured ones,
random output codes, and every fast method — LSH, both code families, PQ, ITQ, brute force — on
shrinkage-whitened rows too, so that the oracle holds each in its strongest form)
at budgets 1 KB … 1 MB on eight maps:

============================== ======================= ============ ==================================
data set                       map                     key          why
============================== ======================= ============ ==================================
Gardens Point day→night        NetVLAD 500-D, N = 200  recall@2     a route (the issue's target)
Gardens Point, permuted        the same rows, map and  recall@0     a real map of independent places
                               queries permuted alike
Gardens Point reversed, and    night→day: the query    recall@2 /   the same route mapped in the other
reversed permuted              traverse as the map     recall@0     condition (not in ``--quick``)
Nordland summer→winter, and    HOG 3780-D, N = 3576    recall@10    the paper's route (10 frames ≈ 2 km)
winter→summer
synthetic route                256-D, N = 2048         recall@2     a route with regions
synthetic independent places   256-D, N = 1000,        recall@0     independent places
                               rows permuted
============================== ======================= ============ ==================================

"btel-codes" rows are the periodic family, "btel-codes random" the random one.

Per map and budget the *oracle* is the best row of the table at that budget (every method and
variant that fits); ``auto`` (:mod:`btel.methods.auto`) chooses from the map and the budget alone, and the
run reports its choice, its recall, the oracle's and their ratio (the target: ≥ 0.95 × the best and
≥ asymmetric LSH on i.i.d. Gaussian hyperplanes, the classic baseline; ``lsh``'s default projection
is a row of its own). *Calibrated auto* is cross-fitted: calibrated on the even queries with their
true places it answers the odd ones, then the other way round (:func:`_calibrated_row`); the figure
rings auto's point in the colour of the row it chose. Brute force (cosine, and on
shrinkage-whitened rows) is the unbudgeted reference of every map.

Every seeded row is the mean over :data:`SEEDS` (two in ``--quick``, and one there for calibrated
auto); a row whose answers do not change between the first two seeds runs once. Cost bounds: one faiss and one BLAS thread, each
row's predicting call timed once (no warm-up, no single-query timing), budgets larger than the
float32 map skipped, the slow registered methods at 64 KB only (summer→winter on Nordland); every
finished row is appended to ``rows.jsonl`` as it comes.
Why each of these: ``docs/decisions/frontier.md``.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from ..evaluation.metrics import recall_at_tolerance
from ..core.storage import check_within_budget, format_bytes, parse_budget
from ..core.threads import limit_threads
from ..datasets.sources import gardens_point_path, load_gardens_point_netvlad
from ..core.claims import atomic_output
from ..exceptions import OutputExistsError
from ._common import SEASONS, ExperimentRun, FittedRow, NordlandData, does_not_fit_cells, fit_and_predict
from .frontier_overview import OVERVIEW_FILE, plot_overview
from .frontier_journal import inputs_digest, journal_bar, journal_line, journalled_rows
from .frontier_verdicts import SEEDS, auto_vs_oracle, paired_difference, report_lines, row_of_choice
from ..methods.registry import make_method

__all__ = ["DATASETS", "SEEDS", "auto_vs_oracle", "exp_frontier", "paired_difference", "report_lines"]

BUDGETS = ("1KB", "4KB", "16KB", "64KB", "256KB", "1MB")
SLOW_BUDGETS = ("64KB",)
#: (label, registry name, params): run at every budget on every map.
FAST = (
    ("auto", "auto", {}),
    ("lsh", "lsh", {}),
    ("lsh centred", "lsh", {"center": True}),
    ("lsh shrink", "lsh", {"whiten": "shrink"}),
    ("lsh hamming", "lsh", {"scoring": "hamming"}),
    ("lsh gaussian", "lsh", {"projection": "gaussian"}),
    ("btel-codes", "btel-codes", {"code": "periodic"}),
    ("btel-codes random", "btel-codes", {"code": "random"}),
    ("btel-codes shrink", "btel-codes", {"code": "periodic", "whiten": "shrink"}),
    ("btel-codes random shrink", "btel-codes", {"code": "random", "whiten": "shrink"}),
    ("pq", "pq", {}),
    ("pq shrink", "pq", {"whiten": "shrink"}),
    ("itq", "itq", {}),
    ("itq shrink", "itq", {"whiten": "shrink"}),
    ("bruteforce", "bruteforce", {}),
    ("bruteforce shrink", "bruteforce", {"whiten": "shrink"}),
)
#: Registered methods that are slow on large maps (module docstring): their fit, or for rabitq its
#: queries (a d × d rotation each: at six budgets, 383 s of one Nordland direction at d = 3780).
SLOW = (
    ("btel-c", "btel-c", {}),
    ("btel-f", "btel-f", {}),
    ("btel-r", "btel-r", {}),
    ("btel-auto", "btel-auto", {}),
    ("ryth", "ryth", {}),
    ("opq", "opq", {}),
    ("rabitq", "rabitq", {}),
    ("seqslam", "seqslam", {}),
)
DATASETS = ("gardens-point", "gardens-point-permuted", "gardens-point reversed", "gardens-point-permuted reversed",
            "nordland summer→winter", "nordland winter→summer", "synthetic route", "synthetic independent")


def row_seeds(name: str, seeds: tuple[int, ...]) -> tuple[int, ...] | None:
    """``seeds`` for a method whose fit draws at random (it has ``random_state``); None for one that
    draws nothing (brute force): it runs once."""
    return seeds if "random_state" in make_method(name).get_params() else None


def slow_budgets(dataset: str, quick: bool) -> tuple[str, ...]:
    """The budgets the :data:`SLOW` rows run at on ``dataset`` (module docstring: cost control)."""
    return () if quick or dataset == "nordland winter→summer" else SLOW_BUDGETS


def _row(base: dict[str, Any], label: str, name: str, params: dict[str, Any], X: np.ndarray, Q: np.ndarray,
         budget: int | None, seeds: tuple[int, ...] | None = None) -> dict[str, Any]:
    """One method at one budget: its recalls, the mean over ``seeds`` (``random_state``; None: unseeded).

    A method whose answers do not change between the first two seeds (its fit draws nothing at
    random here) runs once; ``seed_values`` holds the key recall per seed run.
    """
    row = {**base, "direction": base["dataset"], "method": label, "registry_name": name, "options": dict(params), "budget": budget}
    fits: list[FittedRow] = []
    runs: list[dict[str, float]] = []
    for seed in (None,) if seeds is None else seeds:
        fitted = fit_and_predict(name, params if seed is None else {**params, "random_state": seed}, X, Q, budget,
                                 label, progress=False, timing_repeats=0)
        if not isinstance(fitted, FittedRow):
            return {**row, **fitted}
        if fits and np.array_equal(fitted.pred, fits[0].pred):
            break  # seed-independent: a second seed gave the same answers
        fits.append(fitted)
        runs.append(_recalls(fitted.pred, base["key"]))
    first = fits[0]
    model = first.model
    recalls = {k: float(np.mean([r[k] for r in runs])) for k in runs[0]}
    out = {**row, "status": "ok", "nbytes": int(model.nbytes), "bytes_per_place": model.nbytes / X.shape[0],
           "fit_s": first.fit_s, "query_us": first.query_us, **recalls, "value": recalls[base["key"]],
           "seed_values": [r[base["key"]] for r in runs],
           "half_values": [float(np.mean([r[h] for r in runs])) for h in HALVES],
           "seeds": [] if seeds is None else list(seeds[:len(runs)]),
           "uses_query_sequence": bool(model.uses_query_sequence)}
    choice = model.choice() if hasattr(model, "choice") else None  # what auto chose at fit time
    if choice is not None:
        out.update(_chose(choice))
        out["route_share"] = choice["route_share"]
        out["reason"] = choice["reason"]
    return out


#: The two query halves of the calibrated row (and every row's ``half_values``): even and odd queries.
HALVES = ("even", "odd")


def _halves(n: int) -> dict[str, np.ndarray]:
    """Query indices of each half: interleaved, so both halves cover the whole route."""
    return {"even": np.arange(0, n, 2), "odd": np.arange(1, n, 2)}


def _recalls(pred: np.ndarray, key: str) -> dict[str, float]:
    """recall@0/2/10/20 over every query, and the key recall over each half (:data:`HALVES`)."""
    n = pred.shape[0]
    out = {f"recall@{t}": v for t, v in recall_at_tolerance(pred, np.arange(n), (0, 2, 10, 20)).items()}
    tolerance = int(key.split("@")[1])
    for half, idx in _halves(n).items():
        out[half] = float(recall_at_tolerance(pred[idx], idx, (tolerance,))[tolerance])
    return out


def _chose(choice: dict[str, Any]) -> dict[str, Any]:
    """A fitted auto's choice as row cells: ``chose`` (readable), ``chose_method``, ``chose_params``."""
    return {"chose": choice["method"] + "".join(f" {k}={v}" for k, v in choice["params"].items()),
            "chose_method": choice["method"], "chose_params": dict(choice["params"])}


def _calibrated_row(base: dict[str, Any], X: np.ndarray, Q: np.ndarray, budget: int,
                    seeds: tuple[int, ...]) -> dict[str, Any]:
    """Calibrated auto, cross-fitted: calibrated on one half of the queries (:data:`HALVES`, true place =
    query index, success within the key's tolerance), it answers the other half; then the halves swap.

    Every query is answered by a model that never saw it; per seed (``random_state``, the seeds of
    the other rows, so that the comparison with them is paired) the key recall over all queries,
    ``value`` their mean; ``half_values`` per evaluated half; ``calibrated_choices`` what each
    calibration chose, per half and seed.
    """
    from ..evaluation.measure import timed_fit
    from ..exceptions import BudgetTooSmallError

    row = {**base, "direction": base["dataset"], "method": "auto calibrated", "registry_name": "auto",
           "options": {"calibration": "other half"}, "budget": budget}
    tolerance = int(base["key"].split("@")[1])
    halves = _halves(Q.shape[0])
    runs: list[dict[str, float]] = []
    fit_s, nbytes = [], []
    choices: dict[str, list[dict[str, Any]]] = {h: [] for h in HALVES}
    for seed in seeds:
        pred = np.full(Q.shape[0], -1, dtype=np.int64)
        for evaluated, calibrating in zip(HALVES, HALVES[::-1]):
            cal = halves[calibrating]
            model = make_method("auto", budget=budget, calibration_tolerance=tolerance, random_state=seed)
            try:
                fit_s.append(timed_fit(model, X, calibration=(Q[cal], cal)))
            except BudgetTooSmallError as exc:
                return {**row, **does_not_fit_cells(exc)}
            pred[halves[evaluated]] = model.predict(Q[halves[evaluated]])
            nbytes.append(int(model.nbytes))
            check_within_budget("auto calibrated", nbytes[-1], budget)
            table = model.choice().get("calibration") or {}
            choices[evaluated].append({**_chose(model.choice()), "switched": bool(table.get("switched"))})
        runs.append(_recalls(pred, base["key"]))
    recalls = {k: float(np.mean([r[k] for r in runs])) for k in runs[0]}
    return {**row, "status": "ok", "nbytes": max(nbytes), "bytes_per_place": max(nbytes) / X.shape[0],
            "fit_s": float(np.mean(fit_s)), "query_us": None,
            **{k: v for k, v in recalls.items() if k.startswith("recall@")},
            "value": recalls[base["key"]], "half_values": [recalls[h] for h in HALVES],
            "seed_values": [r[base["key"]] for r in runs], "seeds": list(seeds),
            "calibrated_choices": choices, "uses_query_sequence": False}


def _maps(data: NordlandData, quick: bool) -> list[tuple[dict[str, Any], np.ndarray, np.ndarray]]:
    from ..datasets import synthetic_route

    out = []
    gp = gardens_point_path(data.root.parent)
    if gp.is_file():
        X, Q = load_gardens_point_netvlad(gp)
        out.append(({"dataset": "gardens-point", "regime": "route", "key": "recall@2",
                     "descriptor": "NetVLAD 500-D"}, X, Q))
        perm = np.random.default_rng(0).permutation(X.shape[0])
        out.append(({"dataset": "gardens-point-permuted", "regime": "independent", "key": "recall@0",
                     "descriptor": "NetVLAD 500-D"}, X[perm], Q[perm]))
        if not quick:  # the night traverse as the map, the day one as queries
            out.append(({"dataset": "gardens-point reversed", "regime": "route", "key": "recall@2",
                         "descriptor": "NetVLAD 500-D"}, Q, X))
            out.append(({"dataset": "gardens-point-permuted reversed", "regime": "independent", "key": "recall@0",
                         "descriptor": "NetVLAD 500-D"}, Q[perm], X[perm]))
    if not quick:
        for map_season in SEASONS:
            query_season = SEASONS[1 - SEASONS.index(map_season)]
            X, Q = data.features(map_season, "hog"), data.features(query_season, "hog")
            n = min(len(X), len(Q))
            out.append(({"dataset": f"nordland {map_season}→{query_season}", "regime": "route", "key": "recall@10",
                         "descriptor": "HOG 3780-D"}, X[:n], Q[:n]))
    n_route, n_indep = (256, 200) if quick else (2048, 1000)
    route = synthetic_route(n_route, 64 if quick else 256, condition_shift=1.0, seed=7)
    out.append(({"dataset": "synthetic route", "regime": "route", "key": "recall@2",
                 "descriptor": f"synthetic {route.map.shape[1]}-D"}, route.map, route.queries))
    other = synthetic_route(n_indep, 64 if quick else 256, condition_shift=1.0, seed=11)
    perm = np.random.default_rng(1).permutation(n_indep)
    out.append(({"dataset": "synthetic independent", "regime": "independent", "key": "recall@0",
                 "descriptor": f"synthetic {other.map.shape[1]}-D, rows permuted"}, other.map[perm],
                other.queries[perm]))
    return out


def plot(run: ExperimentRun, out: Path) -> list[Path]:
    """The experiment's figures, from its rows (:func:`_plots`)."""
    return _plots([r.to_row() for r in run.rows], out)


def _plots(rows: list[dict[str, Any]], out: Path) -> list[Path]:
    """Key recall vs stored bytes and vs bytes per place, one panel per map."""
    import matplotlib
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    from matplotlib.lines import Line2D
    from matplotlib.ticker import FuncFormatter, LogLocator, NullFormatter

    written: list[Path] = []

    datasets = list(dict.fromkeys(r["dataset"] for r in rows))
    # One colour and marker per method across every panel (a panel without the 64 KB-only methods
    # would otherwise shift the colour cycle): tab20 colours, the marker changing every ten rows, so
    # no two of the ~25 rows look alike.
    autos = ("auto", "auto calibrated")
    labels = [m for m in dict.fromkeys(r["method"] for r in rows if r.get("status") == "ok") if m not in autos]
    palette = matplotlib.colormaps["tab20"].colors
    styles = {label: {"color": palette[i % len(palette)], "marker": "*" if label.startswith("brute") else "os^Dv"[i // 10 % 5],
                      "linewidth": 1} for i, label in enumerate(labels)}
    styles["auto"] = {"color": "black", "marker": "o", "linewidth": 3}
    styles["auto calibrated"] = {"color": "#7b2cbf", "marker": "s", "linewidth": 1.5, "linestyle": "--",
                                 "markerfacecolor": "none", "markersize": 7}
    for xkey, fname, xlabel in (("nbytes", "frontier_recall_vs_bytes.png", "stored bytes"),
                                ("bytes_per_place", "frontier_recall_vs_bytes_per_place.png", "stored bytes per place")):
        cols = 3
        # The legend (~30 rows) gets a panel of its own: the grid's free cell, or one more row.
        grid_rows = (len(datasets) + cols) // cols
        fig = Figure(figsize=(15, 4.2 * grid_rows), dpi=100)
        FigureCanvasAgg(fig)
        for i, dataset in enumerate(datasets):
            ax = fig.add_subplot(grid_rows, cols, i + 1)
            sub = [r for r in rows if r["dataset"] == dataset and r.get("status") == "ok"]
            for label in dict.fromkeys(r["method"] for r in sub):
                pts = sorted((r[xkey], r["value"]) for r in sub if r["method"] == label)
                ax.plot([p[0] for p in pts], [p[1] for p in pts], label=label, **{"markersize": 4, **styles[label]})
            # auto's pick per budget: a ring in the colour of the row it chose, around auto's point
            for r in sub:
                if r["method"] != "auto":
                    continue
                peers = [o for o in sub if o.get("budget") == r["budget"] and o["registry_name"] != "auto"]
                picked = row_of_choice(peers, r)
                if picked in styles:
                    ax.plot([r[xkey]], [r["value"]], linestyle="none", marker="o", markersize=11,
                            markerfacecolor="none", markeredgewidth=2, markeredgecolor=styles[picked]["color"])
            ax.set_xscale("log")
            # No minor labels on either axis: over less than a decade matplotlib labels its minor ticks
            # (2×10¹, 3×10¹, 4×10¹ …), which run into each other.
            ax.xaxis.set_minor_formatter(NullFormatter())
            if xkey == "nbytes":
                ax.xaxis.set_major_formatter(FuncFormatter(lambda v, _p: format_bytes(v)))
            else:  # 1-2-5 steps over a narrow range, powers of ten over a wide one (as the bytes axes)
                lo, hi = ax.get_xlim()
                decades = np.log10(hi / lo) if lo > 0 else 9.0
                subs = (1.0, 2.0, 5.0) if decades <= 1.5 else (1.0, 3.0) if decades <= 2.5 else (1.0,)
                ax.xaxis.set_major_locator(LogLocator(base=10, subs=subs))
                ax.xaxis.set_major_formatter(FuncFormatter(lambda v, _p: f"{v:g}"))
            ax.set_title(f"{dataset} ({sub[0]['key'] if sub else ''})", fontsize="medium")
            ax.set_xlabel(xlabel)
            ax.set_ylim(0, 1.02)
            ax.grid(True, which="both", alpha=0.3)
        entries: dict[str, Any] = {}
        for ax in fig.axes:
            for handle, label in zip(*ax.get_legend_handles_labels()):
                entries.setdefault(label, handle)
        entries = {**{a: entries[a] for a in autos if a in entries}, **entries}  # auto's two rows first
        ring = Line2D([], [], linestyle="none", marker="o", markersize=9, markerfacecolor="none",
                      markeredgecolor="grey", markeredgewidth=2)
        key = fig.add_subplot(grid_rows, cols, len(datasets) + 1)
        key.axis("off")
        key.legend([*entries.values(), ring], [*entries, "ring: auto's pick (its colour)"], loc="center",
                   ncol=2, fontsize="small", frameon=False, title="method (row)")
        fig.tight_layout()
        fig.savefig(out / fname)
        written.append(out / fname)
    overview = plot_overview(rows, out / OVERVIEW_FILE)  # the README's figure: two maps, six rows
    return written + ([overview] if overview is not None else [])


def exp_frontier(data: NordlandData, out: Path, quick: bool, jobs: int = 1, resume: bool = False) -> ExperimentRun:
    """Every method × budgets on eight maps (four in ``--quick``), auto against the oracle (module docstring).

    ``jobs`` > 1 runs that many maps at once, each in its own process on one thread (joblib), in
    about the longest process's share of the wall time (two: the two Nordland directions side by
    side). Every row is seeded, so the rows are those of one process, but for ITQ's last digits:
    joblib starts its workers with ``OMP_NUM_THREADS`` set, and ITQ's iterated rotation rounds
    differently under BLAS started single-threaded (``docs/decisions/frontier.md``).

    ``resume`` keeps the rows of ``out/rows.jsonl`` (an interrupted run's) that were measured by the
    same btel source on the same map bytes in the same mode (each row's ``inputs``:
    :func:`~btel.experiments.frontier_journal.inputs_digest`) and runs only the others.
    """
    out.mkdir(parents=True, exist_ok=True)
    budgets = ("4KB", "64KB") if quick else BUDGETS
    journal = out / "rows.jsonl"
    if journal.is_dir():
        raise OutputExistsError(f"{str(journal)!r} is a folder; the frontier journals its rows in a file of that "
                                "name: remove or rename the folder, or give another --out.")
    maps = _maps(data, quick)
    found = journalled_rows(journal) if resume else {}
    plans = [_map_plan(base["dataset"], X, budgets, quick) for base, X, _ in maps]
    done = {}  # per map's inputs, the rows of its plan found in the journal
    for (_, X, Q), plan in zip(maps, plans):
        digest = inputs_digest(X, Q, quick)
        keys = {(label, budget) for label, _n, _p, budget, _s in plan}
        done[digest] = {key: row for key, row in found.get(digest, {}).items() if key in keys}
    kept = [row for rows in done.values() for row in rows.values()]
    with atomic_output(journal, text=True) as fh:  # the rows that will be reused, and nothing else
        fh.writelines(journal_line(row) for row in kept)
    parts: list[tuple[list[dict[str, Any]], float]] = []
    total = sum(len(plan) for plan in plans)
    with limit_threads(1), journal_bar(journal, total, data.progress) as bar:
        def log(msg: str) -> None:
            if data.progress:  # above the bar, and flushed: the line of a map that took minutes
                bar.write(f"  {msg}")
                sys.stdout.flush()

        if jobs <= 1:
            pending: Any = (_one_map(base, X, Q, budgets, quick, journal, done) for base, X, Q in maps)
        else:
            from joblib import Parallel, delayed

            # in map order, each as soon as it and the maps before it are done
            pending = Parallel(n_jobs=min(jobs, len(maps)), return_as="generator")(
                delayed(_one_map)(base, X, Q, budgets, quick, journal, done) for base, X, Q in maps)
        for (base, _, _), (map_rows, map_seconds) in zip(maps, pending):
            parts.append((map_rows, map_seconds))
            log(f"{base['dataset']}: {map_seconds:.0f} s; auto " + ", ".join(
                f"{format_bytes(r['budget'])} {r['chose']} {r['value']:.3f}"
                for r in map_rows if r["method"] == "auto" and r["status"] == "ok"))
    rows = [row for map_rows, _ in parts for row in map_rows]
    seconds = {base["dataset"]: s for (base, _, _), (_, s) in zip(maps, parts)}
    run = ExperimentRun.from_rows("frontier", rows, out, plot=plot)
    run.extra = {"auto_vs_oracle": auto_vs_oracle(rows), "part_seconds": seconds,
                 "total_seconds": sum(seconds.values()), "jobs": max(1, min(jobs, len(maps))), "resumed_rows": len(kept)}
    if quick:
        run.extra["quick_protocol"] = (
            f"Quick mode: {len(maps)} maps ({', '.join(b['dataset'] for b, _, _ in maps)}), budgets "
            f"{' and '.join(budgets)}, the rows {', '.join(label for label, _, _ in FAST[:5])}, calibrated auto and "
            f"brute force; seeded rows at seeds {', '.join(map(str, SEEDS[:2]))} (calibrated auto: {SEEDS[0]}). "
            "The oracle is the best of these rows only, so auto's choice may be a method that is not among "
            "them and its ratio may pass 1; no count of cells is drawn.")
    return run


def _map_plan(dataset: str, X: np.ndarray, budgets: tuple[str, ...], quick: bool) -> list[tuple[Any, ...]]:
    """The rows of one map in the order they run: ``(label, registry name, params, budget, seeds)``
    (budget None: unbudgeted; the label ``'auto calibrated'`` is :func:`_calibrated_row`'s)."""
    raw = X.shape[0] * X.shape[1] * 4
    sizes = [parse_budget(b) for b in budgets if parse_budget(b) <= raw]
    plan: list[tuple[Any, ...]] = []
    for label, name, params in FAST[:5] if quick else FAST:
        seeds = row_seeds(name, SEEDS[:2] if quick else SEEDS)
        plan += [(label, name, params, budget, seeds) for budget in sizes]
    plan += [("auto calibrated", "auto", {}, budget, SEEDS[:1] if quick else SEEDS) for budget in sizes]
    plan += [(label, name, params, parse_budget(budget), None)
             for label, name, params in SLOW for budget in slow_budgets(dataset, quick)]
    plan += [(label, "bruteforce", params, None, None)
             for label, params in (("brute force (cosine)", {}), ("brute force shrink", {"whiten": "shrink"}))]
    return plan


def _one_map(base: dict[str, Any], X: np.ndarray, Q: np.ndarray, budgets: tuple[str, ...], quick: bool,
             journal: Path, done: dict[str, dict[tuple[Any, ...], dict[str, Any]]] | None = None,
             ) -> tuple[list[dict[str, Any]], float]:
    """Every row of :func:`_map_plan` on one map: its rows (each new one appended to ``journal`` as it
    finishes, one write per line, so that processes running other maps can share the file) and its
    seconds. A row of ``done`` (rows of an earlier run by inputs digest, then method label and
    budget) measured on these inputs is reused."""
    with limit_threads(1):  # again: a worker process of ``jobs`` > 1 does not inherit the limit
        start = time.perf_counter()
        rows: list[dict[str, Any]] = []
        inputs = inputs_digest(X, Q, quick)
        reusable = (done or {}).get(inputs, {})
        base = {**base, "n_places": int(X.shape[0]), "inputs": inputs}
        for label, name, params, budget, seeds in _map_plan(base["dataset"], X, budgets, quick):
            if (label, budget) in reusable:
                rows.append(reusable[label, budget])
                continue
            rows.append(_calibrated_row(base, X, Q, budget, seeds) if label == "auto calibrated"
                        else _row(base, label, name, params, X, Q, budget, seeds))
            with open(journal, "a") as fh:
                fh.write(journal_line(rows[-1]))
        return rows, time.perf_counter() - start
