"""Output codes against LSH on long ordered maps: does a map of many more places than dimensions defeat the codes?

``btel-codes`` fits one linear classifier per code column on d features. A linear classifier on d
features separates at most about 2·d points in general position (Cover 1965), so on a map of
N ≫ d places the short-period columns, which must change sign every few places, cannot be learned:
the codes then locate a query only to within about N / d places, whatever their bits. LSH has no
such limit. Auto's step 2 (:mod:`btel.methods.auto.rule`) gives an ordered map the codes when LSH's
effective bits per row are below 2 × 2·log2 N; it was set on maps of N ≤ 2000 places, N / d ≤ 8.

Synthetic routes (``synthetic_route(n, d, condition_shift, noise, seed=41)``: ``synthetic_route``'s
default mild change and the easy and hard changes of ``auto_rule_cone_route.py``) of N = 2000, 8000 and 32,000 places at
d = 64, 256 and 1024 (N / d from 2 to 500), under budgets that give LSH 0.7, 1.2 and 1.8 × the
birthday bound 2·log2 N bits per row — the band where step 2 gives the codes. ``lsh`` and
``btel-codes`` (periodic) at seeds 0 … ``--seeds`` − 1, scored on up to 2,000 queries spread evenly
along the route: recall within 2 places (the frontier's key for routes) and within 10.

    python benchmarks/studies/auto_rule_codes_capacity.py            # ≈ 10 min on one thread
    python benchmarks/studies/auto_rule_codes_capacity.py --dims 64   # one width
    python benchmarks/studies/auto_rule_codes_capacity.py --smooth    # routes that take auto's step 1
    python benchmarks/studies/auto_rule_codes_capacity.py --summary   # the table of every run written

Writes ``benchmarks/results/auto_rule_codes_capacity[_<dims>].json`` and prints one row per cell.
"""

from __future__ import annotations

import argparse
import json
import os
import time
from collections import defaultdict

import numpy as np
from _common import RESULTS_DIR, write_results

from btel.core.threads import limit_threads
from btel.datasets import synthetic_route
from btel.methods import make_method
from btel.methods.auto import CODES_PLACES_PER_DIMENSION, ORDER_BITS_FACTOR, choose_method, collision_bits
from btel.methods.auto.statistics import index_order

SETTINGS = (("mild", 0.3, 0.2), ("easy", 1.0, 0.2), ("hard", 2.5, 0.6))
PLACES = (2000, 8000, 32000)
DIMS = (64, 256, 1024)
#: LSH's bits per row as a multiple of the birthday bound 2·log2 N.
BOUND_MULTIPLES = (0.7, 1.2, 1.8)
QUERIES = 2000


def recall(pred: np.ndarray, truth: np.ndarray, tolerance: int) -> float:
    return float(np.mean(np.abs(np.asarray(pred) - truth) <= tolerance))


def summary() -> None:
    """One markdown row per (route kind, change, LSH bits against the bound) over every results file written."""
    groups: dict[tuple[str, str, float], list[dict]] = defaultdict(list)
    for path in sorted(RESULTS_DIR.glob("auto_rule_codes_capacity*.json")):
        for row in json.loads(path.read_text())["rows"]:
            kind = "smooth" if row["setting"].endswith("smooth") else "detailed"
            groups[(kind, row["setting"].split()[0], row["bound_multiple"])].append(row)
    print("| route | change | LSH bits / 2·log2 N | maps | codes ahead at recall@2 | mean codes − lsh | "
          "codes ahead at recall@10 |")
    print("|---|---|---|---|---|---|---|")
    for (kind, setting, multiple), rows in sorted(groups.items(), key=lambda kv: (kv[0][0], ["mild", "easy", "hard"]
                                                                                 .index(kv[0][1]), kv[0][2])):
        ahead = {t: sum(np.mean(r[f"btel-codes recall@{t}"]) > np.mean(r[f"lsh recall@{t}"]) for r in rows)
                 for t in (2, 10)}
        diff = np.mean([r["codes_minus_lsh_recall@2"] for r in rows])
        print(f"| {kind} | {setting} | {multiple:g} | {len(rows)} | {ahead[2]} | {diff:+.3f} | {ahead[10]} |")
    # Step 2 as it stands (the bound itself past CODES_PLACES_PER_DIMENSION places per dimension) against
    # the factor 2 at every size, on the ordered maps (route maps take step 1 whatever the bits).
    ordered = [r for rows in groups.values() for r in rows if r["index_order"] == "ordered"]
    for label, factor in (("factor 2 at every size", lambda r: ORDER_BITS_FACTOR),
                          (f"the bound itself past {CODES_PLACES_PER_DIMENSION} places per dimension",
                           lambda r: 1.0 if r["n_places"] > CODES_PLACES_PER_DIMENSION * r["n_features"]
                           else ORDER_BITS_FACTOR)):
        for t in (2, 10):
            right = sum((r["lsh_effective_bits"] < factor(r) * collision_bits(r["n_places"]))
                        == (np.mean(r[f"btel-codes recall@{t}"]) > np.mean(r[f"lsh recall@{t}"])) for r in ordered)
            lost = sum(max(np.mean(r[f"btel-codes recall@{t}"]), np.mean(r[f"lsh recall@{t}"]))
                       - np.mean(r[f"btel-codes recall@{t}"] if r["lsh_effective_bits"] < factor(r)
                                 * collision_bits(r["n_places"]) else r[f"lsh recall@{t}"]) for r in ordered)
            print(f"step 2 with {label}: the better of the two at recall@{t} in {right} of {len(ordered)} ordered "
                  f"rows; recall lost to the better, summed: {lost:.3f}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=2)
    parser.add_argument("--dims", type=int, nargs="+", default=list(DIMS))
    parser.add_argument("--places", type=int, nargs="+", default=list(PLACES))
    parser.add_argument("--smooth", action="store_true",
                        help="smooth routes (detail 0.1, noise 0.02: auto's route branch) at 0.7 … 8 × the bound")
    parser.add_argument("--summary", action="store_true", help="print the table of every results file written, run nothing")
    parser.add_argument("--settings", nargs="+", default=[s[0] for s in SETTINGS], choices=[s[0] for s in SETTINGS])
    args = parser.parse_args()
    if args.summary:
        return summary()
    start, rows = time.time(), []
    with limit_threads(1):
        for dim in args.dims:
            for n_places in args.places:
                for setting, shift, noise in (s for s in SETTINGS if s[0] in args.settings):
                    shape = {"detail": 0.1, "noise": noise / 10} if args.smooth else {"noise": noise}
                    route = synthetic_route(n_places, dim, condition_shift=shift, seed=41, **shape)
                    X = route.map
                    truth = np.unique(np.linspace(0, n_places - 1, min(QUERIES, n_places)).round().astype(int))
                    Q = route.queries[truth]
                    order = index_order(X, None)
                    for multiple in BOUND_MULTIPLES + ((4.0, 8.0) if args.smooth else ()):
                        bits = multiple * collision_bits(n_places)
                        budget = int(round(n_places * bits / 8))
                        chosen = choose_method(X, None, n_places, budget)[0]
                        scores: dict[str, dict[str, list[float]]] = {}
                        for name, params in (("lsh", {}), ("btel-codes", {"code": "periodic"})):
                            preds = [make_method(name, budget=budget, random_state=seed, **params).fit(X).predict(Q)
                                     for seed in range(args.seeds)]
                            scores[name] = {f"recall@{t}": [recall(p, truth, t) for p in preds] for t in (2, 10)}
                        lsh2, codes2 = (float(np.mean(scores[m]["recall@2"])) for m in ("lsh", "btel-codes"))
                        row = {"n_places": n_places, "n_features": dim, "places_per_dimension": n_places / dim,
                               "setting": setting + (" smooth" if args.smooth else ""), "budget": budget, "bits_per_row": bits,
                               "bound_multiple": multiple, "index_order": order.kind,
                               "continuity": order.continuity, "auto_chose": chosen["method"],
                               "lsh_effective_bits": chosen.get("lsh_effective_bits"), **{
                                   f"{m} {k}": v for m, s in scores.items() for k, v in s.items()},
                               "codes_minus_lsh_recall@2": codes2 - lsh2}
                        rows.append(row)
                        print(f"d {dim:>4} N {n_places:>5} N/d {n_places / dim:>6.1f} {setting:<4} "
                              f"{multiple:.1f}×bound ({bits:.0f} bits, {budget / 1000:.1f} KB, {order.kind})  "
                              f"recall@2 lsh {lsh2:.3f} codes {codes2:.3f}  recall@10 lsh "
                              f"{np.mean(scores['lsh']['recall@10']):.3f} codes "
                              f"{np.mean(scores['btel-codes']['recall@10']):.3f}  auto {chosen['method']}", flush=True)
    whole = args.dims == list(DIMS) and args.places == list(PLACES) and len(args.settings) == len(SETTINGS)
    suffix = "" if whole else "_" + "_".join(map(str, args.dims + args.places + args.settings))
    suffix += "_smooth" if args.smooth else ""
    out = write_results(f"auto_rule_codes_capacity{suffix}", {
        "rows": rows, "seeds": args.seeds, "seconds": time.time() - start, "load": os.getloadavg()})
    print(f"wrote {out} ({time.time() - start:.0f} s)")


if __name__ == "__main__":
    main()
