"""Beyond the paper: can sub-linear BTEL beat quantisation at the same bytes on Nordland?

Measures the target ladder of the "beyond the paper" issue on nordland64 (N = 3576, HOG 3780-D,
both directions) at one byte budget:

1. single frame — the best BTEL variant (ranked output, tolerance-aware codes, regions) against
   the best of PQ / OPQ / ITQ fitted to the same bytes (recall@10);
2. the same at 0.5 MB (run the script with ``--budget 500KB``);
3. with sequences, on equal terms — every method's per-place scores go through the same HMM
   decoder (:mod:`btel.sequence.hmm`); BTEL + HMM should reach recall@10 ≥ 0.5.

The paper's median filter and SeqSLAM's line search over the same scores are measured next to the
HMM; brute force (HOG, 54 MB) and SeqSLAM on patch-normalised thumbnails (7.3 MB) are unbudgeted
references. A per-bit diagnostic figure shows where BTEL loses the information.

Validation protocol (no hyper-parameter sees a reported query): the route is cut into stretches
of 200 frames; stretches 0, 5, 10, 15 (frames 0–199, 1000–1199, 2000–2199, 3000–3199: 800
queries) are the validation queries, the other 2776 are reported. Every model is fitted on the
whole map traverse (all N places; fitting reads no query). Each hyper-parameter — BTEL's C,
block size and region weight, the variant itself, and every method's HMM temperature / vmax /
teleport, median-filter window and SeqSLAM length — is chosen by recall@10 on the validation
queries, then applied once to the reported queries. Sequence decoders restart at the start of
every stretch, so no reported stretch is warmed up on validation frames.

Usage::

    nice -n 10 python benchmarks/study_beyond_paper.py --budget 64KB
    python benchmarks/study_beyond_paper.py --quick            # a small smoke run (first 600 frames)

Writes ``benchmarks/results/study_beyond_paper[_<budget>].json`` and PNG figures beside it.
"""

from __future__ import annotations

import argparse
import itertools
import os
import sys
import time
from pathlib import Path
from typing import Any, Callable


import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import RESULTS_DIR, write_results  # noqa: E402

from btel import BTELocalizer  # noqa: E402
from btel.methods.baselines import SeqSLAM, seqslam_match  # noqa: E402
from btel.methods.btel.diagnostics import localizer_bit_accuracy, plot_bit_accuracy  # noqa: E402
from btel.evaluation import recall_at_k  # noqa: E402
from btel.exceptions import BudgetTooSmallError  # noqa: E402
from btel.methods import make_method  # noqa: E402
from btel.methods.btel.decoding import block_centres  # noqa: E402
from btel.methods.btel.ranking import code_costs, deficits_from_scores, merge_region_kbest  # noqa: E402
from btel.sequence.filter import filter_sequence  # noqa: E402
from btel.sequence.hmm import decode_sequence, emission_scores, zscore_rows  # noqa: E402
from btel.core.storage import format_bytes, parse_budget  # noqa: E402

SEASONS = ("summer", "winter")
STRETCH = 200
VALIDATION_EVERY = 5
TOLERANCES = (0, 1, 5, 10, 20)
KS = (1, 5, 10)
QUANTISERS = ("pq", "opq", "itq")

# Hyper-parameter grids (each chosen on the validation queries).
BTEL_C = (1e-3, 1e-1, 1.0)
BTEL_BLOCKS = (1, 8, 21)  # 1: plain BTE-C; 8 = 2^3 ≤ t = 10 (the rule); 21 = 2t + 1
REGION_WEIGHTS = (1.0, 10.0)
HMM_GRID = {"temperature": (0.1, 0.3, 1.0, 3.0), "vmax": (1, 2, 3, 4), "teleport": (1e-3, 1e-2)}
MEDIAN_WINDOWS = (5, 20)
SEQSLAM_DS = (10, 20)


# ------------------------------------------------------------------------------------ protocol
def split(n: int) -> tuple[np.ndarray, np.ndarray]:
    """(validation rows, reported rows) of a frame-aligned query traverse of n frames."""
    stretch = np.arange(n) // STRETCH
    val = stretch % VALIDATION_EVERY == 0
    return np.flatnonzero(val), np.flatnonzero(~val)


def stretch_starts(rows: np.ndarray) -> np.ndarray:
    """Positions (within ``rows``) where a new contiguous stretch starts."""
    return np.flatnonzero(np.diff(np.concatenate([[-2], rows])) > 1)


def runs(rows: np.ndarray) -> list[slice]:
    starts = list(stretch_starts(rows)) + [rows.size]
    return [slice(a, b) for a, b in zip(starts[:-1], starts[1:])]


def recall(pred: np.ndarray, truth: np.ndarray) -> dict[str, float]:
    err = np.abs(np.asarray(pred) - truth)
    return {f"recall@{t}": float(np.mean(err <= t)) for t in TOLERANCES}


def r_at_k(ranked: np.ndarray, truth: np.ndarray) -> dict[str, float]:
    out = {}
    for tol in (0, 10):
        for k, v in recall_at_k(ranked, truth, ks=KS, tolerance=tol).items():
            out[f"R@{k}" + ("" if tol == 0 else f"(t={tol})")] = v
    return out


# ------------------------------------------------------------------------------------ sequence decoders
def tune(candidates: list[dict[str, Any]], run: Callable[..., np.ndarray], truth: np.ndarray) -> tuple[dict, float]:
    """The candidate with the best validation recall@10 (first wins ties)."""
    best, best_score = candidates[0], -1.0
    for params in candidates:
        score = float(np.mean(np.abs(run(**params) - truth) <= 10))
        if score > best_score:
            best, best_score = params, score
    return best, best_score


def per_run(fn: Callable[[np.ndarray], np.ndarray], values: np.ndarray, rows: np.ndarray) -> np.ndarray:
    return np.concatenate([fn(values[s]) for s in runs(rows)])


def sequence_rows(label: str, S_val: np.ndarray, S_rep: np.ndarray, single_val: np.ndarray,
                  single_rep: np.ndarray, val: np.ndarray, rep: np.ndarray, n: int, base: dict) -> list[dict]:
    """HMM, median filter and SeqSLAM-on-scores for one method, each tuned on validation."""
    out = []
    hmm_grid = [dict(zip(HMM_GRID, v)) for v in itertools.product(*HMM_GRID.values())]
    hmm = lambda S, rows, **p: decode_sequence(S, resets=stretch_starts(rows), **p)  # noqa: E731
    params, v = tune(hmm_grid, lambda **p: hmm(S_val, val, **p), val)
    out.append({**base, "method": f"{label} + HMM", "decoder": "hmm", "selected": params, "val_recall@10": v,
                **recall(hmm(S_rep, rep, **params), rep)})
    med = lambda pred, rows, window: per_run(lambda p: filter_sequence(p, window, n_places=n), pred, rows)  # noqa: E731
    params, v = tune([{"window": a} for a in MEDIAN_WINDOWS], lambda **p: med(single_val, val, **p), val)
    out.append({**base, "method": f"{label} + median filter", "decoder": "median", "selected": params,
                "val_recall@10": v, **recall(med(single_rep, rep, **params), rep)})

    def seq(S: np.ndarray, rows: np.ndarray, ds: int) -> np.ndarray:
        return per_run(lambda s: seqslam_match(-s, ds=ds)[0], S, rows)

    params, v = tune([{"ds": ds} for ds in SEQSLAM_DS], lambda **p: seq(S_val, val, **p), val)
    out.append({**base, "method": f"{label} + SeqSLAM search", "decoder": "seqslam", "selected": params,
                "val_recall@10": v, **recall(seq(S_rep, rep, **params), rep)})
    return out


# ------------------------------------------------------------------------------------ one direction
def load(cache: Path, season: str, descriptor: str, quick: int | None) -> np.ndarray:
    path = cache / f"nordland64-{season}-{descriptor}.npy"
    if not path.is_file():
        from btel.descriptors.extract import extract_cached

        root = Path(os.environ.get("BTEL_NORDLAND", Path(__file__).resolve().parents[2] / "shared" / "data" / "nordland64"))
        extract_cached(root / season, path, descriptor, progress=False)
    X = np.load(path, mmap_mode="r")
    return np.ascontiguousarray(X[:quick] if quick else X, dtype=np.float32)


def _margins_and_deficits(model: BTELocalizer, Q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Every tree's column margins and each region's score deficit ``s_max − s_k`` (fitted BTEL, r regions)."""
    margins = model.column_margins(Q).astype(np.float64)
    region_scores = None if model.n_regions_ == 1 else model.region_hyperplanes_.margins(
        model.front_end_.transform(Q, check_finite=True, lazy=True))  # the queries as column_margins sees them
    return margins, deficits_from_scores(region_scores, model.n_regions_, Q.shape[0])


def ranked_places(model: Any, Q: np.ndarray, k: int, region_weight: float = 1.0) -> np.ndarray:
    """The k best places per query, best first.

    ``model.rank`` (every method; for BTEL the best-first search over bit flips of the predicted
    region's tree, regions merged by cost = flip cost + 1·region deficit). Another region weight α
    (BTEL, compressed, plain bits) merges the per-region k-best lists with α·deficit instead.
    """
    if region_weight == 1.0:
        return model.rank(Q, k)
    margins, deficits = _margins_and_deficits(model, Q)
    codes, _ = merge_region_kbest(margins, deficits, model.region_starts_, model.region_sizes_, model.tree_offsets_,
                                  min(k, int(model.n_blocks_)), region_weight=region_weight)
    return block_centres(codes, model.block_size_, model.n_places_)


def sequence_emissions(model: Any, Q: np.ndarray, region_weight: float = 1.0) -> np.ndarray:
    """HMM emissions: the per-place scores z-scored per row (BTEL: −(flip cost + α·region deficit))."""
    if region_weight == 1.0:
        return emission_scores(model, Q)  # zscore_rows(model.place_scores(Q))
    margins, deficits = _margins_and_deficits(model, Q)
    costs = code_costs(margins, deficits, model.region_starts_, model.region_sizes_, model.tree_offsets_,
                       code_copies=model.code_copies_, region_weight=region_weight)
    if model.block_size_ > 1:  # every place costs what its block costs
        costs = costs[:, np.arange(int(model.n_places_)) // model.block_size_]
    return zscore_rows(-costs)


def evaluate_method(label: str, model: Any, X: np.ndarray, Q: np.ndarray, val: np.ndarray, rep: np.ndarray,
                    base: dict, *, scores: bool = True, region_weight: float = 1.0) -> dict[str, Any]:
    """Fit (if needed), then single-frame recall and R@K on validation and reported queries."""
    t0 = time.perf_counter()
    if not hasattr(model, "n_places_"):
        model.fit(X)
    fit_s = time.perf_counter() - t0
    pred_val, pred_rep = model.predict(Q[val]), model.predict(Q[rep])
    row = {**base, "method": label, "nbytes": int(model.nbytes), "fit_s": fit_s, "decoder": "single",
           "val_recall@10": float(np.mean(np.abs(pred_val - val) <= 10)), **recall(pred_rep, rep)}
    row.update(r_at_k(ranked_places(model, Q[rep], max(KS), region_weight), rep))
    extra = {"model": model, "pred_val": pred_val, "pred_rep": pred_rep}
    if scores:
        extra["S_val"] = sequence_emissions(model, Q[val], region_weight).astype(np.float32)
        extra["S_rep"] = sequence_emissions(model, Q[rep], region_weight).astype(np.float32)
    return {"row": row, **extra}


def run_direction(map_season: str, budget: int, args: argparse.Namespace) -> dict[str, Any]:
    query_season = SEASONS[1 - SEASONS.index(map_season)]
    direction = f"{map_season}→{query_season}"
    X = load(args.hog_cache, map_season, "hog", args.quick)
    Q = load(args.hog_cache, query_season, "hog", args.quick)
    n = X.shape[0]
    val, rep = split(n)
    base = {"direction": direction, "budget": budget}
    rows: list[dict] = []
    seq_rows: list[dict] = []
    log = lambda *a: print(f"[{direction}]", *a, flush=True)  # noqa: E731

    # -- quantisers, fitted to the same bytes ----------------------------------------------------
    for name in QUANTISERS:
        try:
            res = evaluate_method(name.upper(), make_method(name, budget=budget), X, Q, val, rep,
                                  {**base, "family": "quantiser"})
        except BudgetTooSmallError as exc:
            rows.append({**base, "family": "quantiser", "method": name.upper(), "decoder": "single",
                         "status": f"does not fit (needs ≥ {exc.minimum} B)"})
            log(name, "does not fit")
            continue
        res["row"]["config"] = str(getattr(res["model"], "config_", getattr(res["model"], "code_bits_", "")))
        rows.append(res["row"])
        seq_rows += sequence_rows(name.upper(), res["S_val"], res["S_rep"], res["pred_val"], res["pred_rep"],
                                  val, rep, n, {**base, "family": "quantiser"})
        log(name, f"{res['row']['recall@10']:.3f}", "HMM", f"{seq_rows[-3]['recall@10']:.3f}")

    # -- BTEL: the paper's configuration, then the variants ------------------------------------
    def btel(**kw: Any) -> BTELocalizer:
        return BTELocalizer(budget=budget, progress=False, random_state=0, n_jobs=1, **kw)

    paper = evaluate_method("BTE-C (paper: C=1, constrained)", btel(), X, Q, val, rep,
                            {**base, "family": "btel-paper"}, scores=False)
    rows.append(paper["row"])
    diag_models: dict[str, Any] = {"BTE-C HOG (paper, C=1)": paper["model"]}
    log("paper BTE-C", f"{paper['row']['recall@10']:.3f}")

    variants: list[dict[str, Any]] = []
    for C, B in itertools.product(BTEL_C if not args.quick else (1e-1,), BTEL_BLOCKS):
        if B == 1:
            model = btel(C=C, decode="soft")
            label = f"BTE-C soft+ranked C={C:g}"
        else:
            model = btel(C=C, block_size=B)
            label = f"BTE-C tolerant B={B} C={C:g}"
        res = evaluate_method(label, model, X, Q, val, rep, {**base, "family": "btel", "C": C, "block_size": B})
        variants.append(res)
        log(label, f"val {res['row']['val_recall@10']:.3f} rep {res['row']['recall@10']:.3f}",
            f"{res['row']['fit_s']:.0f}s")
    best_C = max(variants, key=lambda r: (r["row"]["val_recall@10"], -r["row"]["block_size"]))["row"]["C"]
    for alpha in REGION_WEIGHTS:
        model = btel(C=best_C, n_regions=20, decode="soft")
        label = f"BTEL r=20 C={best_C:g} α={alpha:g}"
        res = evaluate_method(label, model, X, Q, val, rep, {**base, "family": "btel", "C": best_C, "block_size": 1,
                                                              "n_regions": 20, "region_weight": alpha},
                              region_weight=alpha)
        variants.append(res)
        log(label, f"val {res['row']['val_recall@10']:.3f} rep {res['row']['recall@10']:.3f}")
    for res in variants:
        rows.append(res["row"])
        seq_rows += sequence_rows(res["row"]["method"], res["S_val"], res["S_rep"], res["pred_val"], res["pred_rep"],
                                  val, rep, n, {k: v for k, v in res["row"].items()
                                                if k in ("direction", "budget", "family", "C", "block_size")})
    diag_models[f"BTE-C HOG soft C={best_C:g}"] = next(r["model"] for r in variants
                                                      if r["row"]["C"] == best_C and r["row"]["block_size"] == 1)
    diag_models[f"tolerant B=8 C={best_C:g}"] = next(r["model"] for r in variants
                                                    if r["row"]["C"] == best_C and r["row"]["block_size"] == 8)

    # -- unbudgeted references ----------------------------------------------------------------
    bf = evaluate_method("brute force HOG (unbudgeted)", make_method("bruteforce"), X, Q, val, rep,
                         {**base, "family": "reference"})
    rows.append(bf["row"])
    seq_rows += sequence_rows("brute force HOG", bf["S_val"], bf["S_rep"], bf["pred_val"], bf["pred_rep"], val, rep, n,
                              {**base, "family": "reference"})
    del bf
    Xp = load(args.pn_cache, map_season, "patchnorm", args.quick)
    Qp = load(args.pn_cache, query_season, "patchnorm", args.quick)
    seqslam = SeqSLAM().fit(Xp)
    pred = per_run(lambda q: seqslam.predict(q), Qp[rep], rep)
    rows.append({**base, "family": "reference", "method": "SeqSLAM patchnorm (unbudgeted)", "decoder": "seqslam",
                 "nbytes": int(seqslam.nbytes), **recall(pred, rep)})
    pn_model = BTELocalizer(budget=budget, progress=False, random_state=0, n_jobs=1).fit(Xp)
    diag = {label: localizer_bit_accuracy(m, Q[rep], rep) for label, m in diag_models.items()}
    diag["BTE-C patchnorm (paper, C=1)"] = localizer_bit_accuracy(pn_model, Qp[rep], rep)
    diag["BTE-C HOG (paper) on its own map"] = localizer_bit_accuracy(paper["model"], X[rep], rep)
    return {"direction": direction, "rows": rows, "sequence_rows": seq_rows, "diagnostics": diag, "n_places": n}


# ------------------------------------------------------------------------------------ ladder
def ladder(result: dict[str, Any]) -> dict[str, Any]:
    """The issue's targets, reading only reported-query recall of validation-selected variants."""
    rows, seq = result["rows"], result["sequence_rows"]
    fitted = [r for r in rows if "recall@10" in r]
    quant = [r for r in fitted if r["family"] == "quantiser"]
    btel = [r for r in fitted if r["family"] == "btel"]
    best_btel = max(btel, key=lambda r: r["val_recall@10"])  # selected on validation
    best_q = max(quant, key=lambda r: r["recall@10"]) if quant else None  # quantisers: no tuning
    hmm = [r for r in seq if r["decoder"] == "hmm"]
    btel_hmm = max((r for r in hmm if r["family"] == "btel"), key=lambda r: r["val_recall@10"])
    q_hmm = [r for r in hmm if r["family"] == "quantiser"]
    best_q_hmm = max(q_hmm, key=lambda r: r["recall@10"]) if q_hmm else None
    return {
        "direction": result["direction"],
        "single": {"btel": best_btel["method"], "btel_recall@10": best_btel["recall@10"],
                   "quantiser": best_q["method"] if best_q else None,
                   "quantiser_recall@10": best_q["recall@10"] if best_q else None,
                   "holds": best_q is None or best_btel["recall@10"] >= best_q["recall@10"]},
        "sequence": {"btel": btel_hmm["method"], "btel_recall@10": btel_hmm["recall@10"],
                     "quantiser": best_q_hmm["method"] if best_q_hmm else None,
                     "quantiser_recall@10": best_q_hmm["recall@10"] if best_q_hmm else None,
                     "btel_beats_quantisers": best_q_hmm is None or btel_hmm["recall@10"] >= best_q_hmm["recall@10"],
                     "btel_reaches_0.5": btel_hmm["recall@10"] >= 0.5},
    }


def print_table(result: dict[str, Any]) -> None:
    print(f"\n== {result['direction']} (reported queries; val = validation recall@10 used for selection)")
    head = f"{'method':<44} {'bytes':>10} {'val@10':>7} " + " ".join(f"{'@' + str(t):>6}" for t in TOLERANCES)
    print(head + f" {'R@1':>6} {'R@10':>6}")
    for r in result["rows"] + result["sequence_rows"]:
        if "recall@10" not in r:
            print(f"{r['method']:<44} {r.get('status', '')}")
            continue
        size = format_bytes(r["nbytes"]) if r.get("nbytes") else "-"
        val = f"{r['val_recall@10']:.3f}" if "val_recall@10" in r else "-"
        print(f"{r['method'][:44]:<44} {size:>10} {val:>7} "
              + " ".join(f"{r[f'recall@{t}']:6.3f}" for t in TOLERANCES)
              + (f" {r['R@1']:6.3f} {r['R@10']:6.3f}" if "R@1" in r else ""))


def print_diagnostics(result: dict[str, Any], n: int) -> None:
    need = np.log2(n / 21)
    print(f"\n== per-bit accuracy on the reported queries, {result['direction']} (level 1 = MSB); "
          f"information = Σ_k I(true bit; predicted bit), recall@10 needs ≈ {need:.1f} bits per frame")
    for label, d in result["diagnostics"].items():
        acc = " ".join(f"{a:.2f}" for a in d.accuracy)
        region = "" if d.region_accuracy is None else f"  region acc {d.region_accuracy:.3f}"
        print(f"{label:<36} {acc}  | {np.nansum(d.mutual_information):.3f} bits{region}")


def plot_ladder(results: list[dict[str, Any]], path: Path) -> None:
    fig = Figure(figsize=(9, 4.4), dpi=120)
    FigureCanvasAgg(fig)
    for i, res in enumerate(results):
        ax = fig.add_subplot(1, len(results), i + 1)
        fitted = [r for r in res["rows"] if "recall@10" in r and r["family"] in ("quantiser", "btel", "btel-paper")]
        hmm = {r["method"][: -len(" + HMM")]: r["recall@10"] for r in res["sequence_rows"] if r["decoder"] == "hmm"}
        labels = [r["method"].replace(" (paper: C=1, constrained)", " paper") for r in fitted]
        y = np.arange(len(fitted))
        ax.barh(y - 0.2, [r["recall@10"] for r in fitted], height=0.4, label="single frame")
        ax.barh(y + 0.2, [hmm.get(r["method"], 0.0) for r in fitted], height=0.4, label="+ HMM (same decoder)")
        ax.set_yticks(y, labels, fontsize=6)
        ax.axvline(0.5, color="grey", linestyle=":")
        ax.set_xlim(0, 1)
        ax.set_xlabel("recall@10 (reported queries)")
        ax.set_title(f"{res['direction']}, ≤ {format_bytes(res['rows'][0]['budget'])}", fontsize=9)
        if i == 0:
            ax.legend(fontsize=7, loc="upper right")
    fig.tight_layout()
    fig.savefig(path, format="png")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--budget", default="64KB")
    parser.add_argument("--directions", default="summer,winter", help="map seasons, comma-separated")
    parser.add_argument("--hog-cache", type=Path, default=Path("runs/experiments/cache"))
    parser.add_argument("--pn-cache", type=Path, default=Path("/tmp/btel_cache"))
    parser.add_argument("--quick", type=int, nargs="?", const=600, default=None,
                        help="only the first QUICK frames (default 600) and a reduced grid: a smoke run")
    args = parser.parse_args(argv)
    budget = parse_budget(args.budget)
    start = time.perf_counter()
    results = [run_direction(s, budget, args) for s in args.directions.split(",")]
    ladders = [ladder(r) for r in results]
    for r in results:
        print_table(r)
        print_diagnostics(r, r["n_places"])
    print("\n== ladder")
    for lad in ladders:
        s, q = lad["single"], lad["sequence"]
        print(f"{lad['direction']}: single BTEL {s['btel_recall@10']:.3f} ({s['btel']}) vs quantiser "
              f"{s['quantiser_recall@10'] if s['quantiser_recall@10'] is not None else float('nan'):.3f} ({s['quantiser']})"
              f" → holds: {s['holds']}")
        print(f"{'':>{len(lad['direction'])}}  +HMM  BTEL {q['btel_recall@10']:.3f} ({q['btel']}) vs quantiser "
              f"{q['quantiser_recall@10'] if q['quantiser_recall@10'] is not None else float('nan'):.3f} "
              f"({q['quantiser']}) → beats: {q['btel_beats_quantisers']}, ≥ 0.5: {q['btel_reaches_0.5']}")
    suffix = "" if budget == 64000 and not args.quick else f"_{args.budget}" + ("_quick" if args.quick else "")
    name = f"study_beyond_paper{suffix}"
    fig_bits = RESULTS_DIR / f"{name}_bits.png"
    fig_bal = RESULTS_DIR / f"{name}_bits_balanced.png"
    fig_ladder = RESULTS_DIR / f"{name}.png"
    RESULTS_DIR.mkdir(parents=True, exist_ok=True)
    first = results[0]
    plot_bit_accuracy(first["diagnostics"], fig_bits, title=f"per-bit accuracy, {first['direction']} (reported queries)")
    plot_bit_accuracy(first["diagnostics"], fig_bal, balanced=True,
                      title=f"per-bit balanced accuracy, {first['direction']} (reported queries)")
    plot_ladder(results, fig_ladder)
    payload = {
        "command": " ".join([Path(sys.executable).name] + sys.argv),
        "seconds": time.perf_counter() - start,
        "budget": budget,
        "protocol": __doc__.split("Validation protocol")[1].split("Usage::")[0].strip(),
        "grids": {"btel_C": BTEL_C, "block_sizes": BTEL_BLOCKS, "region_weights": REGION_WEIGHTS, "hmm": HMM_GRID,
                  "median_windows": MEDIAN_WINDOWS, "seqslam_ds": SEQSLAM_DS},
        "ladder": ladders,
        "results": [{"direction": r["direction"], "rows": r["rows"], "sequence_rows": r["sequence_rows"],
                     "bit_diagnostics": {k: v.to_dict() for k, v in r["diagnostics"].items()}} for r in results],
        "figures": [str(p.relative_to(RESULTS_DIR.parent.parent)) for p in (fig_ladder, fig_bits, fig_bal)],
    }
    path = write_results(name, payload)
    print(f"\nwrote {path}, {fig_ladder.name}, {fig_bits.name}, {fig_bal.name}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
