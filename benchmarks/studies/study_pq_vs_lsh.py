"""PQ against LSH (plain, centred) at equal bytes per row while the sign sketch is short of d bits.

A map made for the question, not a frontier map: synthetic routes of N = 2000 places at d = 1024
and 2048 (``btel.datasets.synthetic_route``, two seeds, condition shift 1.0 and 2.0), rows and
queries permuted alike, recall@0 at 32 … 512 bytes per row (P = 256 … 4096 bits < 2d).

    python benchmarks/studies/study_pq_vs_lsh.py
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
from _common import write_results  # noqa: E402


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        description=__doc__.splitlines()[0],
        epilog="Writes benchmarks/results/study_pq_vs_lsh.json.")
    parser.parse_args(argv)
    from btel import make_method
    from btel.core.threads import limit_threads
    from btel.datasets import synthetic_route

    rows = []
    start = time.perf_counter()
    with limit_threads(1):
        for d in (1024, 2048):
            for shift in (1.0, 2.0):
                for seed in (3, 4):
                    r = synthetic_route(2000, d, condition_shift=shift, noise=0.5, seed=seed)
                    perm = np.random.default_rng(seed).permutation(2000)
                    X, Q = r.map[perm], r.queries[perm]
                    for per_row in (32, 64, 128, 256, 512):
                        budget = per_row * 2000
                        out = {
                            "d": d,
                            "shift": shift,
                            "seed": seed,
                            "bytes_per_row": per_row,
                            "bits_per_dimension": round(8 * per_row / d, 3),
                        }
                        for label, name, params in (
                            ("lsh", "lsh", {}),
                            ("lsh centred", "lsh", {"center": True}),
                            ("pq", "pq", {}),
                        ):
                            try:
                                pred = make_method(name, budget=budget, **params).fit(X).predict(Q)
                                out[label] = round(float(np.mean(pred == np.arange(2000))), 4)
                            except (
                                Exception
                            ) as exc:  # noqa: BLE001 - a budget PQ cannot use is a row, not a crash
                                out[label] = None
                                out[label + " error"] = type(exc).__name__
                        rows.append(out)
                        print(out, flush=True)
    write_results(
        "study_pq_vs_lsh",
        {
            "command": "python benchmarks/studies/study_pq_vs_lsh.py",
            "seconds": round(time.perf_counter() - start, 1),
            "rows": rows,
        },
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
