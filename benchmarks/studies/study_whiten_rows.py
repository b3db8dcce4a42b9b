"""Does whitening need many map rows per dimension? Nordland HOG (d = 3780) subsampled to fewer rows.

Brute force, plain cosine against shrinkage-whitened rows, on every k-th Nordland frame
(k = 28, 14, 7, 4, 2, 1: N = 128 … 3576, N/d = 0.03 … 0.95), both directions, recall within
⌈10 / k⌉ places (≈ the same distance along the route).

    python benchmarks/studies/study_whiten_rows.py --cache CACHE
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
from _common import add_data_arguments, write_results  # noqa: E402


def main(argv: list[str] | None = None) -> int:
    from btel import make_method
    from btel.core.threads import limit_threads
    from btel.experiments._common import NordlandData

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_data_arguments(parser)
    args = parser.parse_args(argv)
    data = NordlandData(args.data, args.cache, progress=False)
    summer, winter = data.features("summer", "hog"), data.features("winter", "hog")
    rows, start = [], time.perf_counter()
    with limit_threads(1):
        for step in (28, 14, 7, 4, 2, 1):
            for X, Q, name in ((summer, winter, "summer→winter"), (winter, summer, "winter→summer")):
                idx = np.arange(0, X.shape[0], step)
                tol = max(1, 10 // step)
                recall = {}
                for label, params in (("plain", {}), ("whitened", {"whiten": "shrink"})):
                    pred = make_method("bruteforce", **params).fit(X[idx]).predict(Q[idx])
                    recall[label] = float(np.mean(np.abs(pred - np.arange(idx.size)) <= tol))
                rows.append(
                    {
                        "direction": name,
                        "n_rows": int(idx.size),
                        "rows_per_dimension": idx.size / 3780,
                        "tolerance": tol,
                        **recall,
                        "difference": recall["whitened"] - recall["plain"],
                    }
                )
                print(rows[-1], flush=True)
    write_results(
        "study_whiten_rows",
        {
            "command": "python benchmarks/studies/study_whiten_rows.py " + " ".join(argv or sys.argv[1:]),
            "seconds": round(time.perf_counter() - start, 1),
            "rows": rows,
        },
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
