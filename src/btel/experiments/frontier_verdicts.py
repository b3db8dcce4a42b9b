"""The frontier's verdicts: auto and calibrated auto against the oracle per cell, and its results section.

:func:`auto_vs_oracle` turns the rows of ``btel experiment frontier`` (:mod:`.frontier`) into one
verdict per map and budget; :func:`report_lines` writes them, and every map's table, into
``docs/results.md`` (called by :mod:`btel.experiments.report`).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from ..core.storage import format_bytes
from ..methods.registry import make_method

__all__ = ["SEEDS", "auto_vs_oracle", "paired_difference", "report_lines", "row_of_choice"]

#: Seeds of every seeded row at every budget (``random_state``); the tables give their mean. One seed
#: alone moved single cells by a few hundredths (LSH on orthogonal against Gaussian hyperplanes).
SEEDS = (0, 1, 2)


def paired_difference(a: dict[str, Any], b: dict[str, Any]) -> dict[str, Any]:
    """Row ``a`` − row ``b`` paired over the seeds both ran: ``{"diff", "diff_se", "diff_seeds"}``.

    A seed-independent row (one run) pairs with every seed of the other. ``diff_se`` is the standard
    error of the mean paired difference (None with one pair).
    """
    va, vb = list(a.get("seed_values") or [a["value"]]), list(b.get("seed_values") or [b["value"]])
    n = max(len(va), len(vb))
    va, vb = (va * n if len(va) == 1 else va), (vb * n if len(vb) == 1 else vb)
    n = min(len(va), len(vb))
    d = np.asarray(va[:n]) - np.asarray(vb[:n])
    return {"diff": float(d.mean()), "diff_se": float(d.std(ddof=1) / np.sqrt(n)) if n > 1 else None, "diff_seeds": n}


def auto_vs_oracle(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Per map and budget: auto's choice and value, calibrated auto's, the oracle (best row), asymmetric
    LSH, and the targets.

    The oracle is the best row that is not auto (auto refits one of them: never its own oracle).
    Calibrated auto is compared with it on every query (each answered by a model calibrated on the
    other half) and, per evaluated half, with the best row on that half.
    """
    out = []
    for dataset in dict.fromkeys(r["dataset"] for r in rows):
        sub = [r for r in rows if r["dataset"] == dataset and r.get("budget") and r.get("status") == "ok"]
        for budget in sorted({r["budget"] for r in sub}):
            here = [r for r in sub if r["budget"] == budget]
            auto = next((r for r in here if r["method"] == "auto"), None)
            calibrated = next((r for r in here if r["method"] == "auto calibrated"), None)
            others = [r for r in here if r["registry_name"] != "auto"] or here
            best = max(others, key=lambda r: r["value"])
            registered = [r for r in others if r["method"] == r["registry_name"]]
            best_registered = max(registered, key=lambda r: r["value"]) if registered else None
            # The reference: asymmetric LSH on i.i.d. Gaussian hyperplanes (``lsh``'s default is structured).
            lsh = next((r for r in here if r["method"] == "lsh gaussian"), None) or \
                next((r for r in here if r["method"] == "lsh"), None)
            entry = {"dataset": dataset, "budget": budget, "key": here[0]["key"],
                     "best": best["method"], "best_value": best["value"],
                     "best_registered": best_registered["method"] if best_registered else None,
                     "best_registered_value": best_registered["value"] if best_registered else None,
                     "lsh": lsh["value"] if lsh else None}
            if auto is not None:
                entry.update({"auto": auto["value"], "auto_chose": auto["chose"], "route_share": auto["route_share"],
                              "auto_pick_row": row_of_choice(others, auto),
                              "ratio": auto["value"] / best["value"] if best["value"] > 0 else 1.0,
                              "meets_0.95": auto["value"] >= 0.95 * best["value"] - 1e-12,
                              "meets_lsh": lsh is None or auto["value"] >= lsh["value"] - 1e-12})
                if lsh is not None:
                    entry.update(paired_difference(auto, lsh))
            if calibrated is not None:
                halves_best = [max(r["half_values"][i] for r in others if r.get("half_values")) for i in range(2)]
                entry.update({
                    "calibrated": calibrated["value"],
                    "calibrated_chose": sorted({c["chose"] for cs in calibrated["calibrated_choices"].values()
                                                for c in cs}),
                    "calibrated_switches": sum(c["switched"] for cs in calibrated["calibrated_choices"].values()
                                               for c in cs),
                    "calibrated_fits": sum(len(cs) for cs in calibrated["calibrated_choices"].values()),
                    "calibrated_ratio": calibrated["value"] / best["value"] if best["value"] > 0 else 1.0,
                    "calibrated_meets_0.95": calibrated["value"] >= 0.95 * best["value"] - 1e-12,
                    "calibrated_half_ratios": [c / b if b > 0 else 1.0
                                               for c, b in zip(calibrated["half_values"], halves_best)],
                })
                if auto is not None:
                    entry["calibrated_minus_auto"] = paired_difference(calibrated, auto)
            out.append(entry)
    return out


def row_of_choice(rows: list[dict[str, Any]], auto: dict[str, Any]) -> str | None:
    """The row (label) of the table auto's choice is: same method, same effective parameters."""
    def effective(name: str, params: dict[str, Any]) -> dict[str, Any]:
        got = make_method(name, **params).get_params(deep=False)
        return {k: v for k, v in got.items() if k not in ("budget", "random_state", "progress", "n_jobs")}

    if "chose_method" not in auto:
        return None
    target = effective(auto["chose_method"], auto["chose_params"])
    return next((r["method"] for r in rows
                 if r["registry_name"] == auto["chose_method"] and effective(r["registry_name"], r["options"]) == target),
                None)


# -- the docs/results.md section (called by btel.experiments.report) ---------------------------------------------
def _signed(verdict: dict[str, Any]) -> str:
    """"+0.012 ± 0.008" (paired over seeds), "+0.012" with one pair, "" without LSH."""
    if verdict.get("diff") is None:
        return ""
    se = verdict.get("diff_se")
    return f"{verdict['diff']:+.3f}" + ("" if se is None else f" ± {se:.3f}")


def _counts(verdicts: list[dict[str, Any]]) -> list[str]:
    """The targets in two sentences: cells where (calibrated) auto ≥ 0.95 × best, and the means."""
    autos = [v for v in verdicts if "auto" in v]
    both = [v for v in autos if "calibrated" in v]
    if not autos:
        return []
    text = f"Map-only auto ≥ 0.95 × the best row in {sum(v['meets_0.95'] for v in autos)} of {len(autos)} cells."
    if both:
        text += (f" Calibrated auto (every query answered by a model calibrated on the other half) in "
                 f"{sum(v['calibrated_meets_0.95'] for v in both)} of {len(both)}; mean key recall over these cells "
                 f"{np.mean([v['calibrated'] for v in both]):.3f} calibrated against "
                 f"{np.mean([v['auto'] for v in both]):.3f} map-only.")
    return ["", text]


def report_lines(payload: dict[str, Any], docs_dir: Path) -> list[str]:
    """The "frontier" section of docs/results.md: who wins where, auto against the oracle, every table."""
    rows = payload["rows"]
    verdicts = payload.get("auto_vs_oracle", [])
    parts = payload.get("part_seconds") or {}
    quick = bool((payload.get("run") or {}).get("quick"))
    resumed = payload.get("resumed_rows") or 0
    lines = [("Wall time per map (one faiss and one BLAS thread): "
              + ", ".join(f"{k} {v:.0f} s" for k, v in parts.items()) + "."
              + (f" The run was resumed: {resumed} rows came from the interrupted run's journal (same btel source, "
                 "same maps), and these times count only the rows measured after it." if resumed else ""))
             if parts else "", "",
             payload.get("quick_protocol", "") if quick else
             "Key recall per map (route maps: recall within 2 frames, Nordland within 10; independent places: "
             "exact place, recall@0). Oracle = the best row of the table at that budget (every method and variant "
             "that fits); auto chooses from the map and budget alone; calibrated auto also from half of the queries with "
             "their true places (even or odd queries, interleaved), answers the other half, then the halves swap, "
             "so no query is answered by a model calibrated on it. To bound the run's time, BTE-C, BTE-F, "
             "BTEL with regions, btel-auto, RYTH, OPQ, RaBitQ and SeqSLAM run at 64 KB only and not on Nordland "
             "winter→summer (RaBitQ at every budget: benchmarks/bench_rabitq.py) "
             "(empty cells); a budget larger than the map itself in float32 is not run for any method (Gardens Point "
             "at 1 MB: brute force stores its 400 KB map in less); – = does not fit the budget. Every seeded row "
             f"(all but brute force and the 64 KB-only methods) is the mean over seeds {', '.join(map(str, SEEDS))} "
             "(random_state); a row whose answers did not change with the seed ran once. One seed alone moved "
             "single cells by a few hundredths. 'auto − LSH' is auto's recall minus asymmetric LSH on i.i.d. "
             "Gaussian hyperplanes (the reference column; 'lsh' is its default projection), paired "
             "by seed, ± the standard error of the mean difference.", "",
             "| map | budget | best (oracle) | best registered method | asymmetric LSH (Gaussian) | auto's choice | auto | "
             "auto / best | ≥ 0.95 × best | ≥ LSH | auto − LSH | calibrated auto (switched / fits) | calibrated | "
             "calibrated / best | ≥ 0.95 × best | calibrated − auto |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    lines[1:1] = [] if quick else _counts(verdicts)
    for v in verdicts:
        reg = "" if v["best_registered"] is None else f"{v['best_registered']} {v['best_registered_value']:.3f}"
        lsh = "" if v["lsh"] is None else f"{v['lsh']:.3f}"
        cells = [v["dataset"], format_bytes(v["budget"]), f"{v['best']} {v['best_value']:.3f}", reg, lsh]
        if "auto" in v:
            cells += [v["auto_chose"], f"{v['auto']:.3f}", f"{v['ratio']:.2f}", "yes" if v["meets_0.95"] else "**no**",
                      "yes" if v["meets_lsh"] else "**no**", _signed(v)]
        else:
            cells += ["does not fit", "", "", "", "", ""]
        if "calibrated" in v:
            cells += [f"{', '.join(v['calibrated_chose'])} ({v['calibrated_switches']} / {v['calibrated_fits']})",
                      f"{v['calibrated']:.3f}", f"{v['calibrated_ratio']:.2f}",
                      "yes" if v["calibrated_meets_0.95"] else "**no**",
                      _signed(v.get("calibrated_minus_auto") or {})]
        else:
            cells += ["", "", "", "", ""]
        lines.append("| " + " | ".join(cells) + " |")
    lines.append("")
    for dataset in dict.fromkeys(r["dataset"] for r in rows):
        sub = [r for r in rows if r["dataset"] == dataset]
        budgets = sorted({r["budget"] for r in sub if r.get("budget")})
        key = sub[0]["key"]
        lines += [f"### {dataset} ({sub[0]['descriptor']}, N = {sub[0]['n_places']}): {key}", "",
                  "| method | " + " | ".join(format_bytes(b) for b in budgets) + " |", "|---|" + "---|" * len(budgets)]
        for method in dict.fromkeys(r["method"] for r in sub if r.get("budget")):
            cells = []
            for b in budgets:
                r = next((r for r in sub if r["method"] == method and r.get("budget") == b), None)
                cells.append("" if r is None else (f"{r['value']:.3f}" if r["status"] == "ok" else "–"))
            lines.append(f"| {method} | " + " | ".join(cells) + " |")
        refs = [r for r in sub if r.get("budget") is None and r.get("status") == "ok"]
        lines.append("")
        lines += [f"Reference (no budget): {r['method']} {r[key]:.3f} at {format_bytes(r['nbytes'])}." for r in refs]
        lines.append("")
    return lines
