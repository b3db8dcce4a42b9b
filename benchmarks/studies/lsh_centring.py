"""LSH with and without the map mean subtracted (``center=True`` / ``False``), and the map's cone ratio.

For each map of ``btel experiment frontier`` and budgets 16 KB, 64 KB and 256 KB, ``lsh`` (asymmetric
scoring, its default projection) is fitted centred and uncentred under seeds 0 … ``--seeds`` − 1 and
scored by that map's key recall (recall@2 on Gardens Point and the synthetic route, recall@10 on
Nordland, recall@0 on maps of independent places). The cone ratio (‖mean row‖ / RMS row length of
the L2-normalised map, :func:`btel.methods.baselines.lsh.cone_ratio`) is what ``center='auto'`` reads.
One BLAS thread.

    python benchmarks/studies/lsh_centring.py       # ≈ 3 min on 2 shared cores

Writes ``benchmarks/results/bench_lsh_center.json`` and prints the table.
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np
from _common import add_data_arguments, frontier_maps, key_recall, paired_difference, signed, write_results

from btel.core.frontend import normalize_rows
from btel.methods import make_method
from btel.methods.baselines.lsh import cone_ratio
from btel.core.threads import limit_threads

BUDGETS = (16_000, 64_000, 256_000)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=3)
    add_data_arguments(parser)
    args = parser.parse_args()
    start, rows = time.time(), []
    with limit_threads(1):
        for base, X, Q in frontier_maps(args):
            ratio = cone_ratio(normalize_rows(X.astype(np.float32), "l2"))
            for budget in BUDGETS:
                if budget > X.size * 4:
                    continue
                values = {name: [key_recall(make_method("lsh", budget=budget, center=center,
                                                        random_state=seed).fit(X).predict(Q), base["key"])
                                 for seed in range(args.seeds)]
                          for name, center in (("centred", True), ("uncentred", False))}
                row = {"dataset": base["dataset"], "key": base["key"], "budget": budget, "cone_ratio": ratio,
                       **values, **paired_difference(values["centred"], values["uncentred"])}
                rows.append(row)
                print(f"{base['dataset']:<24} cone {ratio:.2f} {budget // 1000:>4} KB  "
                      f"centred {np.mean(values['centred']):.3f}  "
                      f"uncentred {np.mean(values['uncentred']):.3f}  "
                      f"difference {signed(row)}  ({base['key']})", flush=True)
    out = write_results("bench_lsh_center", {"rows": rows, "seeds": args.seeds,
                                             "seconds": time.time() - start, "load": os.getloadavg()})
    print(f"wrote {out} ({time.time() - start:.0f} s)")


if __name__ == "__main__":
    main()
