"""Study of ``auto``: the map-only rule and the calibrated choice on every frontier map, 1 KB … 1 MB.

For every map of ``btel experiment frontier`` and every budget, every calibration candidate
(:data:`btel.methods.auto.calibrate.CANDIDATES`) is fitted on the whole map at seeds 0 and 1 and its
per-query correctness (the map's key tolerance) kept. From those:

- *best*: the best candidate's recall (mean over the seeds) — the oracle of this study;
- *map-only*: the rule's pick (:func:`btel.methods.auto.choose_method`, the first that fits);
- *calibrated*: the even queries calibrate (:func:`btel.methods.auto.calibrate.decide`, the same
  decision ``fit(X, calibration=…)`` makes when the map is not subsampled), the odd ones evaluate,
  then swapped; the best row and the map-only pick are read on the same evaluation halves.

Every candidate result is appended to ``--rows`` as it comes (a rerun reuses them). The figures and
the markdown tables go to ``benchmarks/results/study_auto.json`` and ``--markdown``.

    python benchmarks/studies/study_auto.py --cache /tmp/h37cache --markdown /tmp/study_auto.md
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
from _common import RESULTS_DIR, add_data_arguments, frontier_maps, write_results  # noqa: E402

BUDGETS = ("1KB", "4KB", "16KB", "64KB", "256KB", "1MB")
TOLERANCE = {"recall@0": 0, "recall@2": 2, "recall@10": 10}


def _label(method: str, params: dict[str, Any]) -> str:
    from btel.methods.auto.calibrate import calibration_candidates

    for c in calibration_candidates():
        if c["method"] == method and c["params"] == params:
            return c["label"]
    return method + "".join(f" {k}={v}" for k, v in sorted(params.items()))


def candidate_rows(
    key: str,
    X: np.ndarray,
    Q: np.ndarray,
    budget: int,
    tol: int,
    skip: set[str],
    cache: dict[tuple[str, int, str], dict[str, Any]],
    out: Path,
) -> dict[str, dict[str, Any]]:
    """Every candidate's per-query correctness (mean over seeds) on every query, from the cache or fitted."""
    from btel import make_method
    from btel.exceptions import BudgetTooSmallError
    from btel.methods.auto import choose_method
    from btel.methods.auto.calibrate import SEEDS, calibration_candidates

    truth = np.arange(Q.shape[0])
    cands = calibration_candidates()
    rule = choose_method(X, None, X.shape[0], budget)
    for c in rule:  # the rule's candidates too (the map-only pick may be none of the calibrated ones)
        if all(c["method"] != d["method"] or c["params"] != d["params"] for d in cands):
            cands.append(
                {
                    "label": _label(c["method"], c["params"]),
                    "method": c["method"],
                    "params": dict(c["params"]),
                    "seeded": c["method"] != "bruteforce",
                }
            )
    rows: dict[str, dict[str, Any]] = {}
    for c in cands:
        if c["label"] in skip:
            continue
        if (key, budget, c["label"]) in cache:
            rows[c["label"]] = cache[(key, budget, c["label"])]
            continue
        start, runs = time.perf_counter(), []
        try:
            for seed in SEEDS if c["seeded"] else (None,):
                params = c["params"] if seed is None else {**c["params"], "random_state": seed}
                model = make_method(c["method"], budget=budget, **params).fit(X)
                runs.append((np.abs(model.predict(Q) - truth) <= tol).astype(np.float64))
            row = {
                "status": "ok",
                "correct": np.mean(runs, axis=0).round(3).tolist(),
                "nbytes": int(model.nbytes),
                "unused": int(getattr(model, "unused_budget", lambda: 0)()),
            }
        except BudgetTooSmallError:
            row = {"status": "does not fit"}
        row.update(
            {
                "map": key,
                "budget": budget,
                "label": c["label"],
                "method": c["method"],
                "params": c["params"],
                "seconds": round(time.perf_counter() - start, 2),
            }
        )
        with out.open("a") as fh:
            fh.write(json.dumps(row) + "\n")
        cache[(key, budget, c["label"])] = rows[c["label"]] = row
        print(f"  {key} {budget} {c['label']}: {row['status']} {row['seconds']} s", flush=True)
    return rows


def cell(key: str, X: np.ndarray, budget: int, rows: dict[str, dict[str, Any]]) -> dict[str, Any]:
    """Best, map-only and calibrated recall of one map at one budget."""
    from btel.methods.auto import choose_method
    from btel.methods.auto.calibrate import decide

    correct = {k: np.asarray(r["correct"]) for k, r in rows.items() if r["status"] == "ok"}
    rule = choose_method(X, None, X.shape[0], budget)
    pick = next(_label(c["method"], c["params"]) for c in rule if _label(c["method"], c["params"]) in correct)
    n = len(next(iter(correct.values())))
    halves = (np.arange(0, n, 2), np.arange(1, n, 2))
    calibrated, best_eval, map_eval, chosen, confidence = [], [], [], [], []
    for cal, ev in (halves, halves[::-1]):
        table = [{"candidate": k, "status": "ok", "score": float(v[cal].mean())} for k, v in correct.items()]
        label = decide(table, {k: v[cal] for k, v in correct.items()}, pick)
        chosen.append(label)
        entry = next(e for e in table if e["candidate"] == label)
        confidence.append(entry.get("confidence"))
        calibrated.append(correct[label][ev])
        map_eval.append(correct[pick][ev])
        best_eval.append(max(float(v[ev].mean()) for v in correct.values()))
    best_label = max(correct, key=lambda k: correct[k].mean())
    both = np.concatenate(calibrated).mean()
    return {
        "map": key,
        "budget": budget,
        "best": best_label,
        "best_recall": round(float(correct[best_label].mean()), 4),
        "map_only": pick,
        "map_only_recall": round(float(correct[pick].mean()), 4),
        "map_only_ratio": round(float(correct[pick].mean() / max(correct[best_label].mean(), 1e-12)), 4),
        "calibrated": chosen,
        "calibrated_confidence": confidence,
        "calibrated_recall": round(float(both), 4),
        "calibrated_ratio_halves": [
            round(float(c.mean() / max(b, 1e-12)), 4) for c, b in zip(calibrated, best_eval)
        ],
        "best_eval_halves": [round(b, 4) for b in best_eval],
        "map_only_eval_halves": [round(float(m.mean()), 4) for m in map_eval],
    }


def markdown(cells: list[dict[str, Any]], command: str) -> str:
    lines = [
        f"Command: `{command}`",
        "",
        "| map | budget | best (oracle) | map-only pick | map-only | / best "
        "| calibrated picks (even→odd, odd→even) | calibrated | / best per half |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    from btel.core.storage import format_bytes

    for c in cells:
        lines.append(
            f"| {c['map']} | {format_bytes(c['budget'])} | {c['best']} {c['best_recall']:.3f} "
            f"| {c['map_only']} | "
            f"{c['map_only_recall']:.3f} | {c['map_only_ratio']:.2f} | {' / '.join(c['calibrated'])} | "
            f"{c['calibrated_recall']:.3f} | {' / '.join(f'{r:.2f}' for r in c['calibrated_ratio_halves'])} |"
        )
    ok_map = sum(c["map_only_ratio"] >= 0.95 for c in cells)
    ok_cal = sum(min(c["calibrated_ratio_halves"]) >= 0.95 for c in cells)
    mean_map = np.mean([c["map_only_recall"] for c in cells])
    mean_cal = np.mean([c["calibrated_recall"] for c in cells])
    lines += [
        "",
        f"Map-only ≥ 0.95 × best in {ok_map} of {len(cells)} cells; calibrated ≥ 0.95 × the best row on "
        f"both evaluation halves in {ok_cal} of {len(cells)}; mean recall over the cells: map-only "
        f"{mean_map:.4f}, calibrated {mean_cal:.4f}.",
    ]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    from btel.core.storage import parse_budget
    from btel.core.threads import limit_threads

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_data_arguments(parser)
    parser.add_argument(
        "--rows",
        type=Path,
        default=RESULTS_DIR / "study_auto_rows.jsonl",
        help="candidate results: read, and appended to as they come",
    )
    parser.add_argument(
        "--more-rows", type=Path, nargs="*", default=[], help="more candidate results to read"
    )
    parser.add_argument(
        "--cached-only",
        action="store_true",
        help="fit nothing: the cells whose candidates (the map-only pick at least) are all read",
    )
    parser.add_argument("--maps", nargs="*", default=None, help="dataset names (default: every frontier map)")
    parser.add_argument("--budgets", nargs="*", default=list(BUDGETS))
    parser.add_argument(
        "--skip-large",
        nargs="*",
        default=["opq", "rabitq", "itq"],
        help="candidates left out on maps of more than 2**22 values (their fit or queries take minutes)",
    )
    parser.add_argument("--markdown", type=Path, default=None)
    args = parser.parse_args(argv)
    cache: dict[tuple[str, int, str], dict[str, Any]] = {}
    for path in [args.rows, *args.more_rows]:
        for line in path.read_text().splitlines() if path.is_file() else []:
            r = json.loads(line)
            cache[(r["map"], r["budget"], r["label"])] = r
    cells = []
    start = time.perf_counter()
    with limit_threads(1):
        for base, X, Q in frontier_maps(args):
            key = base["dataset"]
            if args.maps and key not in args.maps:
                continue
            skip = set(args.skip_large) if X.size > (1 << 22) else set()
            for b in args.budgets:
                budget = parse_budget(b)
                if args.cached_only:
                    rows = {k[2]: r for k, r in cache.items() if k[0] == key and k[1] == budget}
                else:
                    rows = candidate_rows(key, X, Q, budget, TOLERANCE[base["key"]], skip, cache, args.rows)
                try:
                    cells.append(cell(key, X, budget, rows))
                except StopIteration:  # --cached-only: the map-only pick was not run (yet)
                    print(f"{key} {budget}: the map-only pick has no result; cell left out", flush=True)
                    continue
                cells[-1]["candidates"] = sorted(k for k, r in rows.items() if r["status"] == "ok")
                print(json.dumps(cells[-1]), flush=True)
    command = "python benchmarks/studies/study_auto.py " + " ".join(
        argv if argv is not None else sys.argv[1:]
    )
    write_results(
        "study_auto", {"command": command, "seconds": round(time.perf_counter() - start, 1), "cells": cells}
    )
    text = markdown(cells, command)
    print(text)
    if args.markdown:
        args.markdown.write_text(text + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
