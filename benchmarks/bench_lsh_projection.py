"""LSH's projection: orthonormal blocks of hyperplanes against i.i.d. Gaussian ones, same bits, several seeds.

For each map of ``btel experiment frontier`` (Gardens Point NetVLAD 500-D and the same rows permuted,
Nordland HOG summer→winter, the synthetic route and the synthetic independent places) and each budget,
``lsh`` (asymmetric scoring, its budget rule) is fitted with ``projection="orthogonal"`` and with
``projection="gaussian"`` under seeds 0 … ``--seeds`` − 1, and scored by that map's key recall
(recall@2 on Gardens Point and the synthetic route, recall@10 on Nordland, recall@0 on maps of
independent places). The table gives the mean over seeds and its standard error, and the mean
difference orthogonal − Gaussian with its standard error (the same seed's Gaussian matrix is what
the orthogonal one orthonormalises, so the two are paired). One BLAS and one faiss thread.

    python benchmarks/bench_lsh_projection.py             # ≈ 4 min on 2 shared cores
    python benchmarks/bench_lsh_projection.py --quick     # Gardens Point and small synthetic maps

Writes ``benchmarks/results/bench_lsh_projection.json`` and prints the table.
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np
from _common import add_data_arguments, frontier_maps, key_recall, paired_difference, signed, write_results

from btel.methods import make_method
from btel.threads import limit_threads

BUDGETS = ("4KB", "16KB", "64KB", "256KB")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--quick", action="store_true")
    add_data_arguments(parser)
    args = parser.parse_args()
    start, rows = time.time(), []
    with limit_threads(1):
        for base, X, Q in frontier_maps(args, args.quick):
            for budget in BUDGETS:
                values: dict[str, list[float]] = {"orthogonal": [], "gaussian": []}
                for kind in values:
                    for seed in range(args.seeds):
                        model = make_method("lsh", budget=budget, projection=kind, random_state=seed).fit(X)
                        values[kind].append(key_recall(model.predict(Q), base["key"]))
                row = {"dataset": base["dataset"], "key": base["key"], "budget": budget, "n_bits": model.n_bits_,
                       "n_features": int(X.shape[1]), **values,
                       **paired_difference(values["orthogonal"], values["gaussian"])}
                rows.append(row)
                print(f"{base['dataset']:<24} {budget:>6} {model.n_bits_:>5} bits (d = {X.shape[1]:>4})  "
                      f"orthogonal {np.mean(values['orthogonal']):.3f}  gaussian {np.mean(values['gaussian']):.3f}  "
                      f"difference {signed(row)}  ({base['key']})", flush=True)
    out = write_results("bench_lsh_projection", {"rows": rows, "seeds": args.seeds, "quick": args.quick,
                                                 "seconds": time.time() - start, "load": os.getloadavg()})
    print(f"wrote {out} ({time.time() - start:.0f} s)")


if __name__ == "__main__":
    main()
