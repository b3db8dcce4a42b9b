"""Experiment "beyond": the paper's variants against quantisation at the same bytes (the ladder).

``btel experiment beyond`` measures, in one run:

1. **Nordland** (``nordland64``, HOG 3780-D, N = 3576, both directions) at ≤ 64 KB: every BTEL
   variant — plain BTE-C, tolerance-aware codes (``block_size=8``, the rule for t = 10), offset
   codes (``code_copies=2``), multi-exemplar weights (``exemplar_radius=2``), all three combined,
   regions (r = 20) — against PQ, OPQ and ITQ fitted to the same budget. Each is read four ways:
   single frame, ranked (R@10, where the method ranks), the paper's median filter (a = 20) and the
   HMM decoder over the same per-place scores (:meth:`~btel.methods.base.PlaceLocalizer.predict_sequence`),
   so the quantisers get exactly the sequence decoding BTEL gets.
2. **Gardens Point** (500-D NetVLAD, day → night, N = 200) over budgets 1 KB … 64 KB: where
   sub-linear storage meets a descriptor whose bits transfer across conditions.
3. **Synthetic routes** (N = 2048, d = 256) at 16 KB over the appearance change between map and
   query traverse: where the crossover between BTEL and PQ lies; and several map traverses with
   shared labels (variant 6: BTE-C fitted on two traverses under different conditions).
4. **Diagnostics**: per-bit accuracy on the queries against bit level, per descriptor (HOG and
   patch-normalised thumbnails on Nordland, NetVLAD on Gardens Point) and per variant, beside two
   references that locate the loss: the bits of the unbudgeted nearest neighbour's place (what
   the descriptor itself carries across the condition change) and, for HOG, BTE-C's bits on the
   *next summer frame* when fitted on every other summer frame (generalisation within the map's
   own season, no condition change at all).

Validation protocol (nothing is tuned on reported queries): the Nordland query traverse is cut
into stretches of 200 frames; every fifth stretch (0, 5, 10, 15) holds the validation queries,
the others are reported. Models are fitted on the map traverse only. The one tuned choice — the
HMM temperature and top speed, per method — and the "best variant" of each family (BTEL; PQ /
OPQ / ITQ) are chosen by recall@10 on the validation queries; the reported figures are on the
reported queries only. Sequence decoders restart at every stretch start, so no reported stretch
is warmed up on validation frames. Gardens Point and the synthetic routes are not tuned at all
(every option at its default).
"""

from __future__ import annotations

import itertools
from pathlib import Path
from typing import Any

import numpy as np

from ..evaluation.metrics import DEFAULT_TOLERANCES, recall_at_k, recall_at_tolerance
from ..methods.registry import make_method
from ..exceptions import BudgetTooSmallError
from ..evaluation.plots import NORDLAND_CREDIT, finish_recall_plot, new_figure, plot_method_bars, plot_recall_vs_storage
from ..evaluation.records import EvaluationResult
from ..core.storage import check_within_budget, format_bytes, parse_budget
from ..datasets.sources import gardens_point_path, load_gardens_point_netvlad
from ..evaluation.measure import timed_fit
from ..evaluation.records import does_not_fit_status
from ._common import SEASONS, ExperimentRun, NordlandData, fit_model

__all__ = ["exp_beyond", "plot", "BTEL_VARIANTS", "stretch_split"]

#: label → BTELocalizer options of each variant (all through ``make_method("btel-c", ...)``).
BTEL_VARIANTS: dict[str, dict[str, Any]] = {
    "BTE-C": {},
    "BTE-C blocks B=8": {"block_size": 8},
    "BTE-C offset codes m=2": {"code_copies": 2},
    "BTE-C exemplars e=2": {"exemplar_radius": 2},
    "BTE-C B=8 + m=2 + e=2": {"block_size": 8, "code_copies": 2, "exemplar_radius": 2},
    "BTEL r=20": {"n_regions": 20},
}
QUANTISERS = ("pq", "opq", "itq")
HMM_GRID = {"temperature": (0.3, 1.0, 3.0), "vmax": (2, 4)}
MEDIAN_WINDOW = 20
STRETCH = 200
VALIDATION_EVERY = 5
TOLERANCE = 10


def stretch_split(n_queries: int, stretch: int = STRETCH, every: int = VALIDATION_EVERY
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(validation rows, reported rows, stretch starts) of a query traverse (module docstring)."""
    stretch_of = np.arange(n_queries) // stretch
    val = np.flatnonzero(stretch_of % every == 0)
    rep = np.flatnonzero(stretch_of % every != 0)
    return val, rep, np.arange(0, n_queries, stretch)


def _recalls(pred: np.ndarray, truth: np.ndarray) -> dict[str, float]:
    return {f"recall@{t}": v for t, v in recall_at_tolerance(pred, truth, DEFAULT_TOLERANCES).items()}


def _fit(name: str, params: dict[str, Any], X: np.ndarray, budget: int | None,
         data: NordlandData | None = None) -> tuple[Any, float] | int:
    """(fitted model, seconds), or the minimum bytes when the budget is too small.

    Through the experiments' model cache (:func:`._common.fit_model`); seeded (random_state 0
    where the method has one) so that every run gives the same numbers.
    """
    params = {**({"budget": budget} if budget is not None else {}), **params}
    if "random_state" in make_method(name, **params).get_params():
        params["random_state"] = 0
    try:
        model, seconds, _ = fit_model(name, params, X, data)
    except BudgetTooSmallError as exc:
        return int(exc.minimum or 0)
    return model, seconds


def _single_frame_row(base: dict[str, Any], fitted: tuple[Any, float] | int, Q: np.ndarray,
                      truth: np.ndarray) -> dict[str, Any]:
    """The result row of one fitted method read frame by frame (or its "does not fit" row)."""
    if isinstance(fitted, int):
        return {**base, "status": does_not_fit_status(fitted), "nbytes": None, "minimum_bytes": fitted}
    model, fit_s = fitted
    check_within_budget(base["method"], model.nbytes, base["budget"])
    return {**base, "status": "ok", "nbytes": int(model.nbytes), "fit_s": fit_s, **_recalls(model.predict(Q), truth)}


def _nordland_rows(data: NordlandData, budget: int, quick: bool, log: Any,
                   keep: dict[str, Any]) -> tuple[list[dict], dict]:
    """Part 1: every variant and quantiser, four read-outs, both directions; plus the ladder.

    The summer-map BTEL variants are put in ``keep`` (label → model) for the diagnostics.
    """
    stretch = 50 if quick else STRETCH
    rows: list[dict[str, Any]] = []
    ladder: dict[str, Any] = {}
    for map_season in SEASONS:
        query_season = SEASONS[1 - SEASONS.index(map_season)]
        direction = f"{map_season}→{query_season}"
        X, Q = data.features(map_season, "hog"), data.features(query_season, "hog")
        n = min(len(X), len(Q))
        X, Q = X[:n], Q[:n]
        truth = np.arange(n)
        val, rep, resets = stretch_split(n, stretch)
        candidates = [(label, "btel-c", opts, "btel") for label, opts in BTEL_VARIANTS.items()]
        candidates += [(q.upper(), q, {}, "quantiser") for q in QUANTISERS]
        for label, name, opts, family in candidates:
            if quick and opts.get("n_regions", 1) > 4:
                opts = {**opts, "n_regions": 4}
                label = "BTEL r=4"
            base = {"part": "nordland", "descriptor": "HOG", "direction": direction, "method": label,
                    "registry_name": name, "family": family, "n_places": n, "budget": budget,
                    "options": opts}
            fitted = _fit(name, opts, X, budget, data)
            if isinstance(fitted, int):
                rows.append({**base, "decoder": "single", "status": does_not_fit_status(fitted),
                             "nbytes": None, "minimum_bytes": fitted})
                continue
            model, fit_s = fitted
            check_within_budget(label, model.nbytes, budget)
            if family == "btel" and map_season == "summer":
                keep[label] = model
            common = {**base, "nbytes": int(model.nbytes), "fit_s": fit_s, "status": "ok"}
            single = model.predict(Q)
            ranked = model.rank(Q, 10)
            row = {**common, "decoder": "single", **_recalls(single[rep], rep),
                   "val_recall@10": float(np.mean(np.abs(single[val] - val) <= TOLERANCE)),
                   "R@10": recall_at_k(ranked[rep], rep, (10,), tolerance=TOLERANCE)[10],
                   "val_R@10": recall_at_k(ranked[val], val, (10,), tolerance=TOLERANCE)[10]}
            rows.append(row)
            median = _median_by_stretch(single, resets, n)
            rows.append({**common, "decoder": f"median a={MEDIAN_WINDOW}", **_recalls(median[rep], rep),
                         "val_recall@10": float(np.mean(np.abs(median[val] - val) <= TOLERANCE))})
            rows.append({**common, "decoder": "HMM", **_hmm(model, Q, truth, val, rep, resets)})
            log(f"{direction} {label}: {model.nbytes} B, recall@10 single {row['recall@10']:.3f}, "
                f"HMM {rows[-1]['recall@10']:.3f}")
        ladder[direction] = _ladder(rows, direction)
    return rows, ladder


def _median_by_stretch(single: np.ndarray, resets: np.ndarray, n: int) -> np.ndarray:
    from ..sequence.filter import filter_sequence

    out = np.empty_like(single)
    bounds = list(resets) + [len(single)]
    for a, b in zip(bounds[:-1], bounds[1:]):
        out[a:b] = filter_sequence(single[a:b], MEDIAN_WINDOW, n_places=n)
    return out


def _hmm(model: Any, Q: np.ndarray, truth: np.ndarray, val: np.ndarray, rep: np.ndarray,
         resets: np.ndarray) -> dict[str, Any]:
    """HMM decoding with temperature and vmax chosen on the validation rows."""
    from ..sequence.hmm import decode_sequence, emission_scores

    S = emission_scores(model, Q)
    best: tuple[float, dict[str, Any], np.ndarray] | None = None
    for temperature, vmax in itertools.product(HMM_GRID["temperature"], HMM_GRID["vmax"]):
        pred = decode_sequence(S, temperature=temperature, vmax=vmax, resets=resets)
        score = float(np.mean(np.abs(pred[val] - truth[val]) <= TOLERANCE))
        if best is None or score > best[0]:
            best = (score, {"temperature": temperature, "vmax": vmax}, pred)
    score, params, pred = best  # type: ignore[misc]
    return {**_recalls(pred[rep], truth[rep]), "val_recall@10": score, "hmm": params}


#: Ladder measures: (name, decoder rows, reported key, validation key).
LADDER_MEASURES = (
    ("single frame recall@10", "single", "recall@10", "val_recall@10"),
    ("ranked R@10 (10 candidates, t = 10)", "single", "R@10", "val_R@10"),
    ("HMM sequence decoding recall@10", "HMM", "recall@10", "val_recall@10"),
)


def _ladder(rows: list[dict[str, Any]], direction: str) -> dict[str, Any]:
    """Per measure: best-by-validation BTEL variant vs best-by-validation quantiser (same measure)."""
    out: dict[str, Any] = {}
    for measure, decoder, key, val_key in LADDER_MEASURES:
        ok = [r for r in rows if r["direction"] == direction and r["decoder"] == decoder and r["status"] == "ok"
              and key in r]
        pick: dict[str, Any] = {}
        for family in ("btel", "quantiser"):
            group = [r for r in ok if r["family"] == family]
            if group:
                best = max(group, key=lambda r: (r[val_key], -r["nbytes"]))
                pick[family] = {"method": best["method"], "value": best[key], "nbytes": best["nbytes"]}
        if len(pick) == 2:
            pick["btel_at_least_quantiser"] = pick["btel"]["value"] >= pick["quantiser"]["value"]
        if decoder == "HMM" and "btel" in pick:
            pick["btel_reaches_0.5"] = pick["btel"]["value"] >= 0.5
        n = next((r["n_places"] for r in ok), None)
        if n:
            window = min(2 * TOLERANCE + 1, n) / n
            pick["chance"] = 1 - (1 - window) ** 10 if key == "R@10" else window
        out[measure] = pick
    return out


def _gardens_point_rows(root: Path, quick: bool, log: Any) -> list[dict[str, Any]]:
    """Part 2: budget sweep on Gardens Point NetVLAD (day → night, frame-aligned)."""
    path = gardens_point_path(root.parent)
    if not path.is_file():
        return [{"part": "gardens-point", "method": "-", "status": f"skipped: {path} not found", "n_places": 0,
                 "budget": None}]
    X, Q = load_gardens_point_netvlad(path)
    truth = np.arange(X.shape[0])
    budgets = ["4KB", "16KB"] if quick else ["1KB", "2KB", "4KB", "8KB", "16KB", "32KB", "64KB"]
    methods = [("BTE-C", "btel-c", {}), ("BTE-F", "btel-f", {}), ("BTE-C blocks B=4", "btel-c", {"block_size": 4}),
               ("BTE-C offset codes m=2", "btel-c", {"code_copies": 2}), ("PQ", "pq", {}), ("OPQ", "opq", {}),
               ("ITQ", "itq", {})]
    rows = []
    for budget in budgets:
        b = parse_budget(budget)
        for label, name, opts in methods:
            base = {"part": "gardens-point", "descriptor": "NetVLAD 500-D", "direction": "day→night",
                    "method": label, "registry_name": name, "family": "btel" if name.startswith("btel") else "quantiser",
                    "n_places": int(X.shape[0]), "budget": b, "decoder": "single"}
            rows.append(_single_frame_row(base, _fit(name, opts, X, b), Q, truth))
        log(f"Gardens Point {budget} done")
    bf = make_method("bruteforce").fit(X)
    rows.append({"part": "gardens-point", "descriptor": "NetVLAD 500-D", "direction": "day→night",
                 "method": "brute force", "registry_name": "bruteforce", "family": "reference",
                 "n_places": int(X.shape[0]), "budget": None, "decoder": "single", "status": "ok",
                 "nbytes": int(bf.nbytes), **_recalls(bf.predict(Q), truth)})
    return rows


def _synthetic_rows(quick: bool, log: Any) -> list[dict[str, Any]]:
    """Part 3: recall@10 against appearance change on synthetic routes, BTE-C vs PQ / OPQ at one budget."""
    from ..datasets import synthetic_route

    n, dim, budget = (256, 128, "8KB") if quick else (2048, 256, "16KB")
    shifts = (0.3, 1.0) if quick else (0.2, 0.4, 0.6, 0.8, 1.0, 1.2, 1.5)
    b = parse_budget(budget)
    rows = []
    for shift in shifts:
        # Traverse 0 is the map, 1 the queries, 2 a second map traverse under its own conditions.
        route = synthetic_route(n, dim, n_traverses=3, condition_shift=shift, seed=0)
        truth = np.arange(n)
        for label, name in (("BTE-C", "btel-c"), ("PQ", "pq"), ("OPQ", "opq"), ("BTE-C, 2 map traverses", "btel-c")):
            base = {"part": "synthetic", "descriptor": f"synthetic {dim}-D", "condition_shift": shift,
                    "method": label, "registry_name": name, "family": "btel" if name == "btel-c" else "quantiser",
                    "n_places": n, "budget": b, "decoder": "single"}
            if "traverses" in label:  # variant 6: shared labels across traverses (fit(X, places))
                model = make_method(name, budget=b, random_state=0)
                fitted = (model, timed_fit(model, np.concatenate([route.map, route.traverses[2]]),
                                           np.concatenate([truth, truth])))
            else:
                fitted = _fit(name, {}, route.map, b)
            rows.append(_single_frame_row(base, fitted, route.queries, truth))
        log(f"synthetic shift {shift} done")
    return rows


def _diagnostics(data: NordlandData, root: Path, budget: int, out: Path,
                 hog_models: dict[str, Any]) -> dict[str, Any]:
    """Part 4: per-bit accuracy plots, one per descriptor, one line per variant; returns their numbers."""
    btel = make_method("btel-c")  # BTEL's per-bit diagnostics, asked of the method (its code, its figure)

    def nearest_neighbour_bits(X: np.ndarray, Q: np.ndarray) -> Any:
        """Bits of the brute-force nearest neighbour's place against the true place's bits."""
        nn = make_method("bruteforce").fit(X).predict(Q)
        return btel.answer_bit_accuracy(nn, np.arange(len(Q)), len(X))

    summary: dict[str, Any] = {}
    per_descriptor: dict[str, dict[str, Any]] = {}
    for descriptor, label in (("hog", "Nordland HOG"), ("patchnorm", "Nordland patch-normalised")):
        X, Q = data.features("summer", descriptor), data.features("winter", descriptor)
        n = min(len(X), len(Q))
        curves = {}
        if descriptor == "hog":  # the models of part 1 (summer map), not refitted
            for name, model in hog_models.items():
                curves[name] = model.bit_accuracy(Q[:n], np.arange(n))
            # Within-season generalisation: place k = summer frames 2k (fitted) and 2k + 1 (queried).
            half = n // 2
            fitted = _fit("btel-c", {}, X[0 : 2 * half : 2], budget, data)
            if not isinstance(fitted, int):
                curves["BTE-C, next summer frame (held out)"] = fitted[0].bit_accuracy(
                    X[1 : 2 * half : 2], np.arange(half))
        else:
            fitted = _fit("btel-c", {}, X[:n], budget, data)
            if not isinstance(fitted, int):
                curves["BTE-C"] = fitted[0].bit_accuracy(Q[:n], np.arange(n))
        curves["nearest neighbour's place (unbudgeted)"] = nearest_neighbour_bits(X[:n], Q[:n])
        per_descriptor[label + " summer→winter"] = curves
    gp = gardens_point_path(root.parent)
    if gp.is_file():
        X, Q = load_gardens_point_netvlad(gp)
        curves = {}
        for name, opts in (("BTE-C", {}), ("BTE-C offset codes m=2", {"code_copies": 2})):
            fitted = _fit("btel-c", opts, X, parse_budget("16KB"))
            if not isinstance(fitted, int):
                curves[name] = fitted[0].bit_accuracy(Q, np.arange(len(Q)))
        curves["nearest neighbour's place (unbudgeted)"] = nearest_neighbour_bits(X, Q)
        per_descriptor["Gardens Point NetVLAD day→night (16 KB)"] = curves
    for title, curves in per_descriptor.items():
        if not curves:
            continue
        slug = title.split(" (")[0].lower().replace(" ", "_").replace("→", "_to_").replace("-", "")
        btel.plot_bit_accuracy(curves, out / f"bits_{slug}.png", title=f"per-bit accuracy: {title}", balanced=True)
        summary[title] = {name: d.to_dict() for name, d in curves.items()}
    return summary


def exp_beyond(data: NordlandData, out: Path, quick: bool) -> ExperimentRun:
    """The "beyond the paper" ladder (module docstring)."""
    out.mkdir(parents=True, exist_ok=True)
    budget = parse_budget("16KB" if quick else "64KB")
    log = (lambda msg: print(f"  {msg}", flush=True)) if data.progress else (lambda msg: None)
    hog_models: dict[str, Any] = {}
    rows, ladder = _nordland_rows(data, budget, quick, log, hog_models)
    rows += _gardens_point_rows(data.root, quick, log)
    rows += _synthetic_rows(quick, log)
    diagnostics = _diagnostics(data, data.root, budget, out, hog_models)
    protocol = {"stretch": 50 if quick else STRETCH, "validation_every": VALIDATION_EVERY,
                "tolerance": TOLERANCE, "hmm_grid": HMM_GRID, "median_window": MEDIAN_WINDOW,
                "text": __doc__.split("Validation protocol", 1)[1].strip()}
    run = ExperimentRun.from_rows("beyond", rows, out, plot=plot)
    run.extra = {"ladder": ladder, "diagnostics": diagnostics, "protocol": protocol, "budget": budget}
    return run


def plot(run: ExperimentRun, out_dir: Path) -> list[Path]:
    """The "beyond" experiment: Nordland read-outs per method, Gardens Point vs bytes, synthetic crossover."""
    def part(name: str) -> list[EvaluationResult]:
        return [r for r in run.rows if r.labels.get("part") == name]

    written = []
    for direction in sorted({r.labels["direction"] for r in part("nordland")}):
        path = out_dir / f"nordland_{direction.replace('→', '_to_')}.png"
        plot_method_bars([r for r in part("nordland") if r.labels["direction"] == direction], path, group_key="decoder",
                         title=f"Nordland {direction}, HOG, same budget: recall@10 (reported stretches)",
                         credit=NORDLAND_CREDIT)
        written.append(path)
    gp = [r for r in part("gardens-point") if r.ok and r.budget]
    if gp:
        path = out_dir / "gardens_point_recall_vs_bytes.png"
        plot_recall_vs_storage(gp, path, tolerance=5,
                               title="Gardens Point day→night, NetVLAD 500-D: recall@5 vs stored bytes")
        written.append(path)
    synth = [r for r in part("synthetic") if r.ok]
    if synth:
        fig, ax = new_figure()
        for method in dict.fromkeys(r.name for r in synth):
            pts = sorted((float(r.labels["condition_shift"]), float(r.recall[10])) for r in synth if r.name == method)
            ax.plot([p[0] for p in pts], [p[1] for p in pts], marker="o", label=method)
        budget = synth[0].budget
        path = out_dir / "synthetic_crossover.png"
        finish_recall_plot(fig, ax, path, xlabel="appearance change between map and query traverse (condition_shift)",
                           ylabel="recall@10",
                           title=f"Synthetic route, N = {synth[0].n_map}, ≤ {format_bytes(budget) if budget else '?'}")
        written.append(path)
    return written
