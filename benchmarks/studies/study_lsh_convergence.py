"""Does ``lsh`` converge to cosine brute force on the same (plain) front end as its bits grow?

Asymmetric LSH at 1·d, 4·d and 16·d bits per row (the budget rule's cap) against exact cosine
search, seeds 0–2, on Gardens Point (both directions, recall@2), Nordland HOG (every 6th frame,
both directions, recall within 1 = 6 frames) and the frontier's synthetic maps.

    python benchmarks/studies/study_lsh_convergence.py --cache /tmp/h37cache
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
from _common import add_data_arguments, write_results  # noqa: E402


def _recall(pred: np.ndarray, tolerance: int) -> float:
    return float(np.mean(np.abs(pred - np.arange(pred.shape[0])) <= tolerance))


def main(argv: list[str] | None = None) -> int:
    from btel import make_method
    from btel.core.threads import limit_threads
    from btel.datasets import synthetic_route
    from btel.experiments._common import NordlandData

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_data_arguments(parser)
    args = parser.parse_args(argv)
    gp = args.data.parent / "gardenspoint_netvlad" / "hiddenRepr-GardensPoint.npz"
    with np.load(gp, allow_pickle=False) as z:
        day, night = z["hlrTrain"].astype(np.float32), z["hlrTest"].astype(np.float32)
    data = NordlandData(args.data, args.cache, progress=False)
    summer, winter = data.features("summer", "hog")[::6], data.features("winter", "hog")[::6]
    route = synthetic_route(2048, 256, condition_shift=1.0, seed=7)
    other = synthetic_route(1000, 256, condition_shift=1.0, seed=11)
    perm = np.random.default_rng(1).permutation(1000)
    maps = [
        ("gardens-point", day, night, 2),
        ("gardens-point reversed", night, day, 2),
        ("nordland summer→winter /6", summer, winter, 1),
        ("nordland winter→summer /6", winter, summer, 1),
        ("synthetic route", route.map, route.queries, 2),
        ("synthetic independent", other.map[perm], other.queries[perm], 0),
    ]
    rows = []
    start = time.perf_counter()
    with limit_threads(1):
        for name, X, Q, tol in maps:
            d = X.shape[1]
            exact = _recall(make_method("bruteforce").fit(X).predict(Q), tol)
            for factor in (1, 4, 16):
                runs = [
                    _recall(
                        make_method("lsh", n_bits=min(factor * d, 1 << 16), random_state=s).fit(X).predict(Q),
                        tol,
                    )
                    for s in range(3)
                ]
                rows.append(
                    {
                        "map": name,
                        "n_rows": int(X.shape[0]),
                        "d": int(d),
                        "bits_per_dimension": factor,
                        "bruteforce": round(exact, 4),
                        "lsh_mean": round(float(np.mean(runs)), 4),
                        "lsh_seeds": [round(r, 4) for r in runs],
                        "difference": round(float(np.mean(runs)) - exact, 4),
                    }
                )
                print(rows[-1], flush=True)
    command = "python benchmarks/studies/study_lsh_convergence.py " + " ".join(argv or sys.argv[1:])
    write_results(
        "study_lsh_convergence",
        {"command": command, "seconds": round(time.perf_counter() - start, 1), "rows": rows},
    )
    print(
        "| map | d | bits per row | brute force | lsh (mean of 3 seeds) | difference |\n"
        "|---|---|---|---|---|---|"
    )
    for r in rows:
        print(
            f"| {r['map']} | {r['d']} | {r['bits_per_dimension']}·d | {r['bruteforce']:.3f} "
            f"| {r['lsh_mean']:.3f} | {r['difference']:+.3f} |"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
