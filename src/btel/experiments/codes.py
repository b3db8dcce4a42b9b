"""Experiment "codes": recall against bytes for BTEL's output codes against quantisers.

``btel experiment codes`` measures, in one run, recall at tolerances 0…20 frames (single
prediction) against stored bytes from 1 KB to 1 MB:

1. **Gardens Point** day → night (NetVLAD 500-D, N = 200): ``btel-codes`` (periodic codes, the
   budget-filling planner), every code family (periodic, blocks, random, offset, binary) at every
   weight width (4, 8, 16, 32 bits), periodic codes with the liblinear solver at two budgets,
   today's BTEL (BTE-C, BTE-C with offset codes m = 2), PQ, OPQ and ITQ up to 256 KB, brute force
   (cosine, i.e. L2 on normalised rows, 400 KB; and L2 on the raw rows, the older reference), and
   ``btel-codes`` refitted with four more code seeds at 4–64 KB (the spread a seed makes).
2. **Nordland** HOG 3780-D, N = 3576, both directions, 4 KB … 1 MB: ``btel-codes``, random and
   blocks codes, periodic at 8 and 32 bits (64 KB), BTE-C (16 and 64 KB), PQ, OPQ, ITQ, brute force.
3. **Synthetic routes** (N = 2048, d = 256, appearance change 0.5 and 1.0), 1 KB … 256 KB:
   ``btel-codes``, random and blocks codes, BTE-C, PQ, OPQ, ITQ, brute force.

Every method sees the same front end, rows L2-normalised (the default of every method: the
strongest honest form of brute force and of the quantisers on global descriptors). Each row
carries its bytes (the one storage rule), fit seconds and query time per query in the same run
(brute force's flat search included), so speed is compared in one process on one machine.

Validation protocol: ``btel-codes`` is fixed in advance — periodic codes (the family for
route-ordered maps), ridge α by the rule of :mod:`btel.methods.codes.solvers`, the planner's square
rule and 4-bit weights (:mod:`btel.methods.codes.planning`). The baselines run at their own budget
rules. The targets are read off the ``btel-codes`` rows alone; the other families and
widths are reported beside it, not picked from. One setting was revised after this experiment
first ran: the rule's ρ, chosen as 0.03 on synthetic routes of other seeds, is 0.1 (inside the range
those routes favoured) since a sweep over every route map of the frontier experiment, these
Gardens Point traverses included — in this direction it moved recall within 2 frames by
−0.02 … +0.01, with the traverses swapped by +0.015 … +0.10.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import numpy as np

from ..evaluation.metrics import DEFAULT_TOLERANCES, recall_at_tolerance
from ..core.storage import format_bytes, parse_budget
from ..datasets.sources import gardens_point_path, load_gardens_point_netvlad
from ._common import SEASONS, ExperimentRun, FittedRow, NordlandData, docstring_markdown, fit_and_predict

__all__ = ["exp_codes", "TARGETS", "check_targets"]

GP_BUDGETS = ("1KB", "2KB", "4KB", "8KB", "16KB", "32KB", "64KB", "128KB", "256KB", "512KB", "1MB")
#: Gardens Point budgets the quantisers run at: on 200 map rows their largest configurations are
#: reached by 256 KB (PQ's at 82 KB; OPQ and ITQ refit at 512 KB and 1 MB took 2–4 minutes each and
#: changed recall within 2 frames by ≤ 0.09 in a first full run), so they stop there to keep the run short.
GP_QUANTISER_MAX = 256_000
NORDLAND_BUDGETS = ("4KB", "16KB", "64KB", "256KB", "1MB")
SYNTHETIC_BUDGETS = ("1KB", "4KB", "16KB", "64KB", "256KB")
FAMILIES = ("periodic", "blocks", "random", "offset", "binary")
WIDTHS = (4, 8, 16, 32)
QUANTISERS = (("PQ", "pq"), ("OPQ", "opq"), ("ITQ", "itq"))
TODAY = (("BTE-C", "btel-c", {}), ("BTE-C offset m=2", "btel-c", {"code_copies": 2}))
EXTRA_SEEDS = (1, 2, 3, 4)
#: The issue's targets on Gardens Point day → night (single prediction, frames of tolerance).
TARGETS = (
    {"name": "≤ 32 KB: R@2 ≥ 0.50", "budget": 32_000, "key": "recall@2", "at_least": 0.50},
    {"name": "≤ 32 KB: R@10 ≥ 0.80", "budget": 32_000, "key": "recall@10", "at_least": 0.80},
    {"name": "≤ 64 KB: R@2 ≥ 0.62", "budget": 64_000, "key": "recall@2", "at_least": 0.62},
)
MAIN = "btel-codes"


def _recalls(pred: np.ndarray, truth: np.ndarray) -> dict[str, float]:
    return {f"recall@{t}": v for t, v in recall_at_tolerance(pred, truth, DEFAULT_TOLERANCES).items()}


def _row(base: dict[str, Any], name: str, params: dict[str, Any], X: np.ndarray, Q: np.ndarray,
         budget: int | None) -> dict[str, Any]:
    """Fit one method (or record that it does not fit), predict every query, time both."""
    row = {**base, "registry_name": name, "budget": budget, "options": {k: v for k, v in params.items()}}
    fitted = fit_and_predict(name, params, X, Q, budget, base["method"])
    if not isinstance(fitted, FittedRow):
        return {**row, **fitted}
    out = {**row, "status": "ok", "nbytes": int(fitted.model.nbytes), "fit_s": fitted.fit_s,
           "query_us": fitted.query_us, **_recalls(fitted.pred, np.arange(Q.shape[0]))}
    if fitted.model.summary():
        out["configuration"] = fitted.model.summary()
    return out


def _sweep(part: dict[str, Any], X: np.ndarray, Q: np.ndarray, budgets: tuple[str, ...],
           methods: list[tuple[str, str, dict[str, Any], str]], log: Any,
           quantiser_max: int | None = None) -> list[dict[str, Any]]:
    """Every (label, registry name, params, family) at every budget, then brute force (unbudgeted).

    Quantisers run only up to ``quantiser_max`` bytes when it is given.
    """
    rows = []
    for budget in budgets:
        b = parse_budget(budget)
        for label, name, params, family in methods:
            if family == "quantiser" and quantiser_max is not None and b > quantiser_max:
                continue
            rows.append(_row({**part, "method": label, "family": family}, name, params, X, Q, b))
        main = next((r for r in rows if r["method"] == MAIN and r["budget"] == b and r["status"] == "ok"), None)
        if main:
            log(f"{part['dataset']} {part.get('direction', '')} {budget}: {MAIN} R@2 {main['recall@2']:.3f} "
                f"R@10 {main['recall@10']:.3f} ({main['nbytes']} B)")
    rows.append(_row({**part, "method": "brute force", "family": "reference"}, "bruteforce", {}, X, Q, None))
    return rows


def _codes(label: str, family: str | None = None, bits: int | None = None, **extra: Any) -> tuple:
    params = dict(extra)
    if family is not None:
        params["code"] = family
    if bits is not None:
        params["weight_bits"] = bits
    return (label, "btel-codes", params, "codes")


def _baselines(with_today: bool) -> list[tuple]:
    out = [(label, name, {}, "quantiser") for label, name in QUANTISERS]
    if with_today:
        out += [(label, name, params, "btel") for label, name, params in TODAY]
    return out


def _gardens_point(root: Path, quick: bool, log: Any) -> tuple[list[dict[str, Any]], dict[str, Any]]:
    path = gardens_point_path(root.parent)
    if not path.is_file():
        return [{"part": "gardens-point", "dataset": "Gardens Point", "method": "-", "n_places": 0, "budget": None,
                 "nbytes": None, "status": f"skipped: {path} not found", "minimum_bytes": None}], {}
    X, Q = load_gardens_point_netvlad(path)
    part = {"part": "gardens-point", "dataset": "Gardens Point", "direction": "day→night",
            "descriptor": "NetVLAD 500-D", "n_places": int(X.shape[0])}
    families = ("periodic",) if quick else FAMILIES
    widths = (4, 8) if quick else WIDTHS
    methods = [_codes(MAIN)]
    for family in families:
        for bits in widths:
            methods.append(_codes(f"codes {family} {bits}-bit", family, bits))
    methods += _baselines(with_today=True)
    budgets = ("8KB", "32KB") if quick else GP_BUDGETS
    rows = _sweep(part, X, Q, budgets, methods, log, quantiser_max=GP_QUANTISER_MAX)
    rows.append(_row({**part, "method": "brute force, raw rows (L2)", "family": "reference"}, "bruteforce",
                     {"normalize": "none"}, X, Q, None))
    if not quick:  # the other solver, at two budgets (one SVM per column: slower)
        for budget in ("8KB", "32KB"):
            rows.append(_row({**part, "method": "codes periodic, liblinear", "family": "codes"}, "btel-codes",
                             {"solver": "liblinear"}, X, Q, parse_budget(budget)))
    seeds: dict[str, Any] = {}
    for budget in (("32KB",) if quick else ("4KB", "8KB", "16KB", "32KB", "64KB")):
        b = parse_budget(budget)
        runs = [r for r in rows if r["method"] == MAIN and r["budget"] == b and r["status"] == "ok"]
        for seed in EXTRA_SEEDS[: 1 if quick else None]:
            runs.append(_row({**part, "method": f"{MAIN} seed {seed}", "family": "codes-seed"}, "btel-codes",
                             {"random_state": seed}, X, Q, b))
        rows += runs[1:]
        seeds[str(b)] = {key: {"mean": float(np.mean([r[key] for r in runs])),
                               "min": float(np.min([r[key] for r in runs])),
                               "max": float(np.max([r[key] for r in runs])), "n": len(runs)}
                         for key in ("recall@0", "recall@2", "recall@10")}
    return rows, seeds


def _nordland(data: NordlandData, quick: bool, log: Any) -> list[dict[str, Any]]:
    rows = []
    budgets = ("16KB",) if quick else NORDLAND_BUDGETS
    for map_season in SEASONS[:1] if quick else SEASONS:
        query_season = SEASONS[1 - SEASONS.index(map_season)]
        X, Q = data.features(map_season, "hog"), data.features(query_season, "hog")
        n = min(len(X), len(Q))
        part = {"part": "nordland", "dataset": "Nordland", "direction": f"{map_season}→{query_season}",
                "descriptor": "HOG 3780-D", "n_places": int(n)}
        methods = [_codes(MAIN)] if quick else [_codes(MAIN), _codes("codes random", "random"),
                                                _codes("codes blocks", "blocks")]
        methods += _baselines(with_today=False)[: 1 if quick else None]
        rows += _sweep(part, X[:n], Q[:n], budgets, methods, log)
        if not quick:
            for label, name, params in (("BTE-C", "btel-c", {}),):
                for budget in ("16KB", "64KB"):
                    rows.append(_row({**part, "method": label, "family": "btel"}, name, params, X[:n], Q[:n],
                                     parse_budget(budget)))
            for bits in (8, 32):
                rows.append(_row({**part, "method": f"codes periodic {bits}-bit", "family": "codes"}, "btel-codes",
                                 {"weight_bits": bits}, X[:n], Q[:n], parse_budget("64KB")))
    return rows


def _synthetic(quick: bool, log: Any) -> list[dict[str, Any]]:
    from ..datasets import synthetic_route

    n, dim = (256, 64) if quick else (2048, 256)
    rows = []
    for shift in ((0.5,) if quick else (0.5, 1.0)):
        # Seed 7: the ridge rule was chosen on routes of seeds 0 and 1 (btel.methods.codes.solvers docstring).
        route = synthetic_route(n, dim, condition_shift=shift, seed=7)
        part = {"part": "synthetic", "dataset": "synthetic route", "direction": f"shift {shift}",
                "descriptor": f"synthetic {dim}-D", "condition_shift": shift, "n_places": n}
        methods = [_codes(MAIN), _codes("codes random", "random")] if quick else \
            [_codes(MAIN), _codes("codes random", "random"), _codes("codes blocks", "blocks")]
        methods += _baselines(with_today=True)[: 1 if quick else None]
        rows += _sweep(part, route.map, route.queries, ("8KB",) if quick else SYNTHETIC_BUDGETS, methods, log)
    return rows


def check_targets(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """The issue's targets on Gardens Point, read off the ``btel-codes`` rows (met or missed, with the values)."""
    gp = [r for r in rows if r.get("part") == "gardens-point" and r.get("status") == "ok"]
    out = []
    for target in TARGETS:
        fitting = [r for r in gp if r["method"] == MAIN and r["budget"] and r["budget"] <= target["budget"]]
        best = max(fitting, key=lambda r: r[target["key"]], default=None)
        out.append({"target": target["name"], "value": None if best is None else best[target["key"]],
                    "nbytes": None if best is None else best["nbytes"],
                    "met": bool(best is not None and best[target["key"]] >= target["at_least"])})
    reference = next((r for r in gp if r["method"] == "brute force"), None)
    if reference:
        small = [r for r in gp if r["method"] == MAIN and r["budget"] and r["budget"] <= 32_000]
        best = max(small, key=lambda r: r["recall@10"], default=None)
        out.append({"target": f"≤ 32 KB: R@10 above cosine brute force ({reference['recall@10']:.3f} at "
                              f"{format_bytes(reference['nbytes'])})",
                    "value": None if best is None else best["recall@10"], "nbytes": None if best is None else
                    best["nbytes"], "met": bool(best is not None and best["recall@10"] > reference["recall@10"])})
    budgets = sorted({r["budget"] for r in gp if r["budget"] and 4_000 <= r["budget"] <= 64_000})
    for key in ("recall@2", "recall@10"):
        verdicts = []
        for b in budgets:
            ours = next((r for r in gp if r["method"] == MAIN and r["budget"] == b), None)
            theirs = [r for r in gp if r["budget"] == b and r.get("family") == "quantiser"]
            best = max(theirs, key=lambda r: r[key], default=None)
            verdicts.append({"budget": b, "btel-codes": None if ours is None else ours[key],
                             "best quantiser": None if best is None else f"{best['method']} {best[key]:.3f}",
                             "met": bool(ours is not None and (best is None or ours[key] >= best[key]))})
        out.append({"target": f"every budget 4–64 KB: btel-codes ≥ best of PQ/OPQ/ITQ ({key})", "value": None,
                    "nbytes": None, "met": all(v["met"] for v in verdicts), "per_budget": verdicts})
    return out


def plot(run: ExperimentRun, out: Path) -> list[Path]:
    """The experiment's figures, from its rows (:func:`_plots`)."""
    return _plots([r.to_row() for r in run.rows], out)


def _plots(rows: list[dict[str, Any]], out: Path) -> list[Path]:
    """Recall against bytes, one figure per data set and tolerance (plus the weight widths on Gardens Point)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    from matplotlib.ticker import FuncFormatter

    written: list[Path] = []

    def figure(select, path: Path, key: str, title: str) -> None:
        fig = Figure(figsize=(7.5, 5), dpi=110)
        FigureCanvasAgg(fig)
        ax = fig.add_subplot(1, 1, 1)
        series: dict[str, list[tuple[int, float]]] = {}
        for r in rows:
            if r.get("status") == "ok" and select(r):
                series.setdefault(r["method"], []).append((r["nbytes"], r[key]))
        for label, points in series.items():
            points.sort()
            xs, ys = [p[0] for p in points], [p[1] for p in points]
            style = {"linewidth": 2.5} if label == MAIN else ({"linestyle": "--"} if not label.startswith("codes")
                                                              else {"linewidth": 1})
            marker = "*" if label.startswith("brute force") else "o"
            ax.plot(xs, ys, marker=marker, markersize=10 if marker == "*" else 4, label=label, **style)
        ax.set_xscale("log")
        ax.xaxis.set_major_formatter(FuncFormatter(lambda v, _p: format_bytes(v)))
        ax.set_xlabel("stored bytes")
        ax.set_ylabel(f"recall within {key.split('@')[1]} frames")
        ax.set_ylim(0, 1.02)
        ax.grid(True, which="both", alpha=0.3)
        ax.set_title(title, fontsize="medium")
        ax.legend(fontsize="x-small", ncol=2)
        fig.tight_layout()
        fig.savefig(path)
        written.append(path)

    main_like = {MAIN, "codes blocks", "codes random", "brute force", "brute force, raw rows (L2)",
                 *(label for label, _ in QUANTISERS), *(label for label, _, _ in TODAY)}
    gp_auto = {MAIN, *(f"codes {f} 4-bit" for f in FAMILIES if f != "periodic")}
    for key in ("recall@2", "recall@10"):
        figure(lambda r: r["part"] == "gardens-point" and (r["method"] in main_like | gp_auto),
               out / f"gardens_point_{key.replace('@', '')}_vs_bytes.png", key,
               f"Gardens Point day→night (N = 200, NetVLAD): {key.replace('recall', 'R')} vs bytes")
    figure(lambda r: r["part"] == "gardens-point" and r["method"].startswith("codes periodic ")
           and r["method"].endswith("-bit"), out / "gardens_point_weight_widths.png", "recall@2",
           "Gardens Point: periodic codes at 4 / 8 / 16 / 32-bit weights")
    for part, label in (("nordland", "Nordland HOG"), ("synthetic", "synthetic route")):
        for direction in sorted({r.get("direction") for r in rows if r.get("part") == part}):
            slug = direction.replace("→", "_to_").replace(" ", "_").replace(".", "")
            figure(lambda r, d=direction: r["part"] == part and r.get("direction") == d and r["method"] in main_like,
                   out / f"{part}_{slug}_recall10_vs_bytes.png", "recall@10", f"{label} {direction}: R@10 vs bytes")
    return written


def exp_codes(data: NordlandData, out: Path, quick: bool) -> ExperimentRun:
    """Output codes against quantisers over budgets on three data sets (module docstring)."""
    out.mkdir(parents=True, exist_ok=True)
    log = (lambda msg: print(f"  {msg}", flush=True)) if data.progress else (lambda msg: None)
    timings: dict[str, float] = {}
    start = time.perf_counter()
    rows, seeds = _gardens_point(data.root, quick, log)
    timings["gardens-point"] = time.perf_counter() - start
    start = time.perf_counter()
    rows += _nordland(data, quick, log)
    timings["nordland"] = time.perf_counter() - start
    start = time.perf_counter()
    rows += _synthetic(quick, log)
    timings["synthetic"] = time.perf_counter() - start
    run = ExperimentRun.from_rows("codes", rows, out, plot=plot)
    run.extra = {"targets": check_targets(rows), "seeds": seeds, "part_seconds": timings,
                 "protocol": " ".join(__doc__.split("Validation protocol:", 1)[1].split())}
    return run


# -- the docs/results.md section (called by btel.experiments.report) ---------------------------------------------
def _cell(row: dict[str, Any] | None, keys: tuple[str, ...]) -> str:
    if row is None:
        return ""
    if row.get("status") != "ok":
        return "does not fit"
    return " / ".join(f"{row[k]:.3f}" for k in keys)


def _pivot(rows: list[dict[str, Any]], methods: list[str], keys: tuple[str, ...]) -> list[str]:
    """Methods × budgets, each cell the recalls at ``keys`` (and the bytes are the column's budget)."""
    budgets = sorted({r["budget"] for r in rows if r.get("budget")})
    head = ["method", *[format_bytes(b) for b in budgets]]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for method in methods:
        cells = [_cell(next((r for r in rows if r["method"] == method and r.get("budget") == b), None), keys)
                 for b in budgets]
        if any(cells):
            lines.append("| " + " | ".join([method, *cells]) + " |")
    return lines


def _references(rows: list[dict[str, Any]], budget: int | None) -> list[str]:
    """Bytes, fit and query time of every method at one budget, and brute force, in the same run."""
    pick = [r for r in rows if r.get("status") == "ok" and (r.get("budget") == budget or r.get("budget") is None)
            and r.get("family") != "codes-seed" and not r["method"].startswith("codes ")]
    lines = ["| method | budget | bytes | fit s | query µs/query | R@0 | R@2 | R@10 |", "|---|---|---|---|---|---|---|---|"]
    for r in pick:
        lines.append(f"| {r['method']} | {format_bytes(r['budget']) if r.get('budget') else 'none'} | "
                     f"{format_bytes(r['nbytes'])} | {r['fit_s']:.2f} | {r['query_us']:.1f} | {r['recall@0']:.3f} | "
                     f"{r['recall@2']:.3f} | {r['recall@10']:.3f} |")
    return lines


def _verdicts(rows: list[dict[str, Any]], key: str = "recall@10") -> list[str]:
    """Per budget: btel-codes against the best quantiser that fits (computed, no adjectives)."""
    out = []
    for b in sorted({r["budget"] for r in rows if r.get("budget")}):
        ours = next((r for r in rows if r["method"] == MAIN and r.get("budget") == b and r.get("status") == "ok"), None)
        tried = [r for r in rows if r.get("budget") == b and r.get("family") == "quantiser"]
        theirs = [r for r in tried if r.get("status") == "ok"]
        if ours is None:
            continue
        if not theirs:
            why = "no quantiser fits" if tried else "quantisers not run at this budget"
            out.append(f"{format_bytes(b)}: btel-codes {key} = {ours[key]:.3f}; {why}.")
            continue
        best = max(theirs, key=lambda r: r[key])
        verdict = "wins" if ours[key] > best[key] else ("ties" if ours[key] == best[key] else "loses")
        out.append(f"{format_bytes(b)}: btel-codes {key} = {ours[key]:.3f} ({format_bytes(ours['nbytes'])}) vs "
                   f"{best['method']} {best[key]:.3f} ({format_bytes(best['nbytes'])}) — btel-codes {verdict}.")
    return out


def report_lines(payload: dict[str, Any], docs_dir: Path) -> list[str]:
    """The "codes" section of docs/results.md: targets, tables per data set, timing, seeds, reading."""
    rows = payload["rows"]
    lines = [f"Validation protocol: {docstring_markdown(payload.get('protocol', ''))}", ""]
    targets = payload.get("targets", [])
    if targets:
        lines += ["### Targets (Gardens Point day → night, btel-codes fixed in advance; protocol above)", "",
                  "| target | btel-codes | at bytes | met |", "|---|---|---|---|"]
        for t in targets:
            value = "" if t.get("value") is None else f"{t['value']:.3f}"
            where = "" if t.get("nbytes") is None else format_bytes(t["nbytes"])
            lines.append(f"| {t['target']} | {value} | {where} | {'yes' if t['met'] else '**no**'} |")
            for v in t.get("per_budget", []):
                ours = "" if v["btel-codes"] is None else f"{v['btel-codes']:.3f}"
                lines.append(f"| … at {format_bytes(v['budget'])} | {ours} | best quantiser: "
                             f"{v['best quantiser'] or 'none fits'} | {'yes' if v['met'] else '**no**'} |")
        lines.append("")
    gp = [r for r in rows if r.get("part") == "gardens-point"]
    if gp and gp[0].get("status", "ok") == "ok":
        families = [f"codes {f} 4-bit" for f in FAMILIES]
        methods = [MAIN, *families, "codes periodic, liblinear", *(q for q, _ in QUANTISERS),
                   *(t for t, _, _ in TODAY)]
        lines += ["### Gardens Point day → night (NetVLAD 500-D, N = 200): R@2 / R@10 at each budget", "",
                  "Cells: recall within 2 / within 10 frames, single prediction; the stored bytes of every row "
                  "are in `results.csv` (each ≤ its budget). `codes <family> 4-bit` are the families under the "
                  "same planner; `btel-codes` is the periodic family with the planner choosing the width. "
                  f"PQ, OPQ and ITQ run up to {format_bytes(GP_QUANTISER_MAX)}: on 200 map rows their largest "
                  "configurations are reached by then (PQ's at 82 KB).", ""]
        lines += _pivot(gp, methods, ("recall@2", "recall@10")) + [""]
        lines += ["Weight widths (periodic codes, R@2 / R@10; at a fixed budget a wider weight means fewer codes "
                  "and columns):", ""]
        lines += _pivot(gp, [f"codes {f} {w}-bit" for f in FAMILIES for w in WIDTHS], ("recall@2", "recall@10"))
        lines += ["", "Bytes, fit and query time in the same run at 32 KB (query time: the whole night traverse "
                      "in one batch, per query; brute force is faiss' flat search over the 200 map rows):", ""]
        lines += _references(gp, 32_000) + [""]
        seeds = payload.get("seeds", {})
        if seeds:
            lines += ["Spread over code seeds (btel-codes refitted with seeds 0–4; the reported rows are seed 0):",
                      "", "| budget | fits | R@0 mean (min–max) | R@2 mean (min–max) | R@10 mean (min–max) |",
                      "|---|---|---|---|---|"]
            for b, s in seeds.items():
                cells = [f"{s[k]['mean']:.3f} ({s[k]['min']:.3f}–{s[k]['max']:.3f})"
                         for k in ("recall@0", "recall@2", "recall@10")]
                lines.append(f"| {format_bytes(int(b))} | {s['recall@2']['n']} | " + " | ".join(cells) + " |")
            lines.append("")
        lines += ["Computed (R@10, btel-codes vs the best quantiser that fits):", ""]
        lines += [f"- {s}" for s in _verdicts(gp)] + [""]
    for part, title in (("nordland", "Nordland"), ("synthetic", "Synthetic route")):
        sub = [r for r in rows if r.get("part") == part]
        for direction in sorted({r.get("direction") for r in sub}):
            these = [r for r in sub if r.get("direction") == direction]
            methods = list(dict.fromkeys(r["method"] for r in these if r.get("budget")))
            lines += [f"### {title} ({these[0].get('descriptor')}, N = {these[0]['n_places']}), {direction}: "
                      "R@0 / R@10 at each budget", ""]
            lines += _pivot(these, methods, ("recall@0", "recall@10")) + [""]
            bf = next((r for r in these if r["method"] == "brute force" and r.get("status") == "ok"), None)
            if bf:
                lines.append(f"Brute force (no budget, {format_bytes(bf['nbytes'])}): R@0 {bf['recall@0']:.3f}, "
                             f"R@10 {bf['recall@10']:.3f}, {bf['query_us']:.1f} µs/query; btel-codes at 64 KB: " +
                             next((f"{r['query_us']:.1f} µs/query" for r in these if r["method"] == MAIN
                                   and r.get("budget") == 64_000 and r.get("status") == "ok"), "–") + ".")
                lines.append("")
            lines += [f"- {s}" for s in _verdicts(these)] + [""]
    reading = Path(docs_dir) / "reading-codes.md"
    if reading.is_file():
        lines += ["### Reading", "", reading.read_text().strip(), ""]
    return lines
