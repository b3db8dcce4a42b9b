"""Routes against snippets of a route in random order: the test of auto's route continuity.

Gardens Point (NetVLAD 500-D, N = 200) mapped by day and at night, its rows cut into snippets of
L consecutive frames (L = 1 is the permuted map, 200 the route itself) whose order is shuffled, map
and queries alike. A snippet of 3 already puts most rows' nearest other row within 2 places (route
share ≥ 0.5), so the route share alone sent such maps to the route branch (periodic output codes,
which assume the whole index order is a route); :func:`btel.methods.auto.route_continuity` — the
mean percentile rank of the cosine to the rows 3 … 8 places away — tells them apart. For every L:
the route share, the continuity, auto's choice, and recall@0 (exact place, the shuffled map's only
fair tolerance) of periodic codes, LSH and whitened LSH at 4, 16 and 64 KB (seeds 0 … ``--seeds`` − 1)
and of auto.

    python benchmarks/studies/auto_rule_route_snippets.py      # ≈ 1 min on 2 shared cores

Writes ``benchmarks/results/bench_route_snippets.json`` and prints the table.
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import numpy as np
from _common import key_recall, snippet_order, write_results

from btel.methods import make_method
from btel.methods.auto import route_continuity, route_share
from btel.core.threads import limit_threads

SNIPPETS = (1, 2, 3, 5, 10, 20, 40, 200)
BUDGETS = (4_000, 16_000, 64_000)
CANDIDATES = (("codes", "btel-codes", {"code": "periodic"}), ("lsh", "lsh", {}),
              ("lsh shrink", "lsh", {"whiten": "shrink"}), ("auto", "auto", {}))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=3)
    parser.add_argument("--data", type=Path, default=Path(__file__).resolve().parents[3] / "shared" / "data"
                        / "gardenspoint_netvlad" / "hiddenRepr-GardensPoint.npz")
    args = parser.parse_args()
    with np.load(args.data, allow_pickle=False) as z:
        day, night = z["hlrTrain"].astype(np.float32), z["hlrTest"].astype(np.float32)
    start, rows = time.time(), []
    with limit_threads(1):
        for mapped, (X, Q) in (("day", (day, night)), ("night", (night, day))):
            for length in SNIPPETS:
                order = snippet_order(X.shape[0], length)
                Xs, Qs = X[order], Q[order]
                share, continuity = route_share(Xs), route_continuity(Xs)
                for budget in BUDGETS:
                    values = {label: float(np.mean([key_recall(make_method(name, budget=budget, random_state=seed,
                                                                           **params).fit(Xs).predict(Qs), "recall@0")
                                                    for seed in range(args.seeds)]))
                              for label, name, params in CANDIDATES}
                    chose = make_method("auto", budget=budget).fit(Xs).choice_["method"]
                    rows.append({"mapped": mapped, "snippet": length, "route_share": share, "continuity": continuity,
                                 "budget": budget, "auto_chose": chose, **values})
                    print(f"{mapped:<5} snippets of {length:>3}  share {share:.2f}  continuity {continuity:.2f}  "
                          f"{budget // 1000:>2} KB  codes {values['codes']:.3f}  lsh {values['lsh']:.3f}  "
                          f"lsh shrink {values['lsh shrink']:.3f}  auto ({chose}) {values['auto']:.3f}", flush=True)
    out = write_results("bench_route_snippets", {"rows": rows, "seeds": args.seeds, "seconds": time.time() - start,
                                                 "load": os.getloadavg()})
    print(f"wrote {out} ({time.time() - start:.0f} s)")


if __name__ == "__main__":
    main()
