"""Storage against N: BTE-C grows with log N, BTE-F (and brute force) linearly.

Fits BTE-C for real at every N (fixed d'), and BTE-F for real up to --full-max (its fit time grows
with N); beyond that BTE-F's bytes are the planned bytes (``btel.methods.btel.localizer.planned_bytes``, which
the tests check equals the fitted ``nbytes``).

    python benchmarks/bench_storage.py
"""

from __future__ import annotations

import argparse
import time


from btel import BTELocalizer
from btel.datasets import synthetic_route
from btel.methods.btel.localizer import planned_bytes

from _common import write_results


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--sizes", type=int, nargs="+", default=[1024, 4096, 16384, 65536])
    parser.add_argument("--dim", type=int, default=128)
    parser.add_argument("--n-features", type=int, default=32)
    parser.add_argument("--full-max", type=int, default=4096)
    args = parser.parse_args()

    rows = []
    for n in args.sizes:
        route = synthetic_route(n, args.dim, n_traverses=1, seed=0)
        start = time.perf_counter()
        c = BTELocalizer(n_features=args.n_features, n_jobs=-1).fit(route.map)
        c_fit = time.perf_counter() - start
        if n <= args.full_max:
            f = BTELocalizer(scheme="full", n_features=args.n_features, n_jobs=-1).fit(route.map)
            f_bytes, f_source = f.nbytes, "fitted"
        else:
            f_bytes, f_source = planned_bytes(n, args.dim, n_selected=args.n_features, scheme="full"), "planned"
        rows.append({"n_places": n, "btec_bytes": c.nbytes, "btec_fit_s": c_fit, "btef_bytes": f_bytes,
                     "btef_source": f_source, "bruteforce_bytes": n * args.dim * 4})

    base = rows[0]
    print(f"d = {args.dim}, d' = {args.n_features}")
    print(f"{'N':>7} {'BTE-C B':>9} {'× N0':>6} {'BTE-F B':>12} {'× N0':>7} {'brute force B':>14}")
    for row in rows:
        print(f"{row['n_places']:>7} {row['btec_bytes']:>9,d} {row['btec_bytes'] / base['btec_bytes']:>6.2f} "
              f"{row['btef_bytes']:>12,d} {row['btef_bytes'] / base['btef_bytes']:>7.1f} {row['bruteforce_bytes']:>14,d}"
              f"{'' if row['btef_source'] == 'fitted' else '  (BTE-F planned)'}")
    ratio = rows[-1]["btec_bytes"] / base["btec_bytes"]
    print(f"BTE-C bytes({rows[-1]['n_places']}) / bytes({base['n_places']}) = {ratio:.2f}")
    path = write_results("bench_storage", {"config": vars(args), "rows": rows, "btec_ratio": ratio})
    print(f"written to {path}")


if __name__ == "__main__":
    main()
