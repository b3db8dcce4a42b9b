"""LSH's projection: sign flips + Walsh–Hadamard blocks against QR-orthonormal blocks and Gaussian ones.

For each map of ``btel experiment frontier`` (Gardens Point NetVLAD 500-D, both directions, and the same
rows permuted, Nordland HOG summer↔winter, the synthetic route and the synthetic independent places) and
each budget, ``lsh`` (asymmetric scoring, its budget rule) is fitted with ``projection="hadamard"`` (the
default), ``"orthogonal"`` (the default before it) and ``"gaussian"`` under seeds 0 … ``--seeds`` − 1, and
scored by that map's key recall (recall@2 on Gardens Point and the synthetic route, recall@10 on
Nordland, recall@0 on maps of independent places). The table gives the mean over seeds and the mean
difference hadamard − orthogonal with its standard error (runs paired by seed; the projections draw
different random numbers, so the pairing removes no variance). One BLAS and one faiss thread.

    python benchmarks/studies/lsh_projection.py             # ≈ 5 min on 2 shared cores
    python benchmarks/studies/lsh_projection.py --quick     # Gardens Point and small synthetic maps
    python benchmarks/studies/lsh_projection.py --seeds 20 --maps permuted,"synthetic route" \
        --budgets 4KB,16KB,64KB --name bench_lsh_projection_seeds20     # more seeds on chosen cells

Writes ``benchmarks/results/<name>.json`` (default ``bench_lsh_projection``) and prints the table (the
markdown rows of ``docs/decisions/lsh-projection.md``).
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np
from _common import add_data_arguments, frontier_maps, key_recall, paired_difference, signed, write_results

from btel.methods import make_method
from btel.core.threads import limit_threads

BUDGETS = ("4KB", "16KB", "64KB", "256KB")
KINDS = ("hadamard", "orthogonal", "gaussian")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--maps", default="", help="comma-separated parts of map names to keep (default all)")
    parser.add_argument("--budgets", default=",".join(BUDGETS))
    parser.add_argument("--name", default="bench_lsh_projection", help="result file name")
    add_data_arguments(parser)
    args = parser.parse_args()
    start, rows = time.time(), []
    print("| map | budget | bits | d | hadamard | orthogonal | gaussian | hadamard − orthogonal |")
    print("| --- | --- | ---: | ---: | ---: | ---: | ---: | ---: |")
    with limit_threads(1):
        for base, X, Q in frontier_maps(args, args.quick):
            if args.maps and not any(part in base["dataset"] for part in args.maps.split(",")):
                continue
            for budget in args.budgets.split(","):
                values: dict[str, list[float]] = {kind: [] for kind in KINDS}
                seconds = dict.fromkeys(KINDS, 0.0)
                for kind in KINDS:
                    for seed in range(args.seeds):
                        tic = time.perf_counter()
                        model = make_method("lsh", budget=budget, projection=kind, random_state=seed).fit(X)
                        values[kind].append(key_recall(model.predict(Q), base["key"]))
                        seconds[kind] += time.perf_counter() - tic
                row = {"dataset": base["dataset"], "key": base["key"], "budget": budget,
                       "n_bits": model.n_bits_, "n_features": int(X.shape[1]), **values, "seconds": seconds,
                       **paired_difference(values["hadamard"], values["orthogonal"])}
                rows.append(row)
                means = " | ".join(f"{np.mean(values[kind]):.3f}" for kind in KINDS)
                cell = f"{base['dataset']} ({base['key']}) | {budget} | {model.n_bits_} | {X.shape[1]}"
                print(f"| {cell} | {means} | {signed(row)} |", flush=True)
    out = write_results(args.name, {"rows": rows, "seeds": args.seeds, "quick": args.quick,
                                                 "seconds": time.time() - start, "load": os.getloadavg()})
    print(f"wrote {out} ({time.time() - start:.0f} s)")


if __name__ == "__main__":
    main()
