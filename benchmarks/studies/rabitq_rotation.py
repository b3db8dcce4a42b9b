"""RaBitQ's rotation: the seeded Hadamard rotation (default) against the QR of a Gaussian matrix.

Three parts (``--parts``), one BLAS and one faiss thread:

- **Recall, paired by seed.** ``rabitq`` with ``rotation='hadamard'`` and ``rotation='qr'`` under
  each budget (D and B by the budget rule, nothing tuned), seeds 0 … ``--seeds``−1, scored by
  :func:`btel.evaluation.evaluate`. Maps (query j is place j): Gardens Point NetVLAD 500-D both ways
  (N = 200), Nordland HOG 3780-D summer→winter (N = 3576, extracted once into ``--cache``; every
  4th query and ``--nordland-seeds`` seeds, because faiss' RaBitQ scan with float queries takes
  about 3 ms a query there even at D = 104), and
  synthetic independent places (``synthetic_route(1000, 256, condition_shift=1.0, seed=11)``,
  permuted as ``btel experiment frontier`` does). Key tolerance: 2 on Gardens Point, 10 on Nordland,
  0 on the synthetic map. Each cell: the mean over seeds of both, and of their difference with its
  standard error.
- **The rotation alone** (``projection``): on Nordland HOG summer→winter (L2-normalised rows), the
  first D coordinates of each rotation for D ∈ {104, 536, 2336} (RaBitQ's D at 64 KB and 256 KB is 104
  and 536; at 1 MB it is 2192),
  centred on the map's mean, and the cosine nearest neighbour there, no quantisation: recall@10 over
  every query at ``--projection-seeds`` seeds, paired by seed. This isolates the subspace each
  rotation keeps from RaBitQ's codes, at many more seeds than RaBitQ's slow scan allows.
- **Cost by width.** N = 500 rows of d ∈ {2048, 8192, 16384} (``synthetic_route``), budgets 64 KB and
  1 MB: fit, ``btel.load`` and first-query seconds of each rotation. A QR cell whose d·D² exceeds
  ``--max-qr-flops`` is not run (stated in the row), because it would run for minutes.

    python benchmarks/studies/rabitq_rotation.py                 # ≈ 15 min on 2 shared cores
    python benchmarks/studies/rabitq_rotation.py --quick         # Gardens Point, 2 seeds, d ≤ 8192
    python benchmarks/studies/rabitq_rotation.py --parts projection --name rabitq_rotation_projection

Writes ``benchmarks/results/rabitq_rotation.json`` (``--name``: another name) and prints every row.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from _common import write_results

import btel
from btel.core.storage import parse_budget
from btel.core.threads import limit_threads
from btel.evaluation import evaluate
from btel.exceptions import BudgetTooSmallError
from btel.methods import make_method

HERE = Path(__file__).resolve().parents[1]  # benchmarks/
BUDGETS = ("4KB", "16KB", "64KB", "256KB", "1MB")
ROTATIONS = ("hadamard", "qr")


def maps(shared: Path, cache: Path, quick: bool) -> list[tuple[str, int, np.ndarray, np.ndarray, np.ndarray]]:
    """(name, key tolerance, map, queries, true place of each query) of each map."""
    from btel.datasets import synthetic_route

    with np.load(shared / "gardenspoint_netvlad" / "hiddenRepr-GardensPoint.npz", allow_pickle=False) as z:
        day, night = z["hlrTrain"].astype(np.float32), z["hlrTest"].astype(np.float32)
    every = np.arange(len(day))
    out = [("gardens-point day→night", 2, day, night, every),
           ("gardens-point night→day", 2, night, day, every)]
    if quick:
        return out
    from btel.experiments._common import NordlandData

    data = NordlandData(shared / "nordland64", cache, progress=False)
    X, Q = data.features("summer", "hog"), data.features("winter", "hog")
    n = min(len(X), len(Q))
    fourth = np.arange(0, n, 4)
    out.append(("nordland summer→winter", 10, X[:n], Q[fourth], fourth))
    other = synthetic_route(1000, 256, condition_shift=1.0, seed=11)
    perm = np.random.default_rng(1).permutation(1000)
    out.append(("synthetic independent", 0, other.map[perm], other.queries[perm], np.arange(1000)))
    return out


def recall_cells(shared: Path, cache: Path, quick: bool, seeds: int, nordland_seeds: int) -> list[dict[str, Any]]:
    rows = []
    for name, tol, X, Q, truth in maps(shared, cache, quick):
        for b in BUDGETS:
            budget = parse_budget(b)
            row: dict[str, Any] = {"map": name, "n_places": int(X.shape[0]), "d": int(X.shape[1]),
                                   "budget": b, "tolerance": tol}
            for rotation in ROTATIONS:
                scores, fits = [], []
                for seed in range(nordland_seeds if name.startswith("nordland") else seeds):
                    model = make_method("rabitq", budget=budget, rotation=rotation, random_state=seed)
                    try:
                        result = evaluate(model, X, Q, ground_truth=truth, tolerances=(tol,), ks=(), budget=budget,
                                          timing_repeats=1)
                    except BudgetTooSmallError:
                        break
                    scores.append(float(result.recall[tol]))
                    fits.append(float(result.fit_time_s))
                    row["dim"], row["nbits"] = int(model.dim_), int(model.nbits_)
                row[rotation] = scores
                row[f"{rotation}_fit_s"] = float(np.median(fits)) if fits else None
            if row["hadamard"] and len(row["hadamard"]) == len(row["qr"]):
                diff = np.subtract(row["hadamard"], row["qr"])
                row["difference"] = float(diff.mean())
                row["difference_se"] = float(diff.std(ddof=1) / np.sqrt(len(diff))) if len(diff) > 1 else None
            print(line(row), flush=True)
            rows.append(row)
    return rows


def line(row: dict[str, Any]) -> str:
    if not row["hadamard"]:
        return f"{row['map']:<26} {row['budget']:>6}  does not fit"
    se = row.get("difference_se")
    return (f"{row['map']:<26} {row['budget']:>6}  D = {row['dim']:>4} B = {row['nbits']}  "
            f"hadamard {np.mean(row['hadamard']):.3f}  qr {np.mean(row['qr']):.3f}  "
            f"difference {row['difference']:+.3f}" + (f" ± {se:.3f}" if se is not None else "")
            + f"  fit s {row['hadamard_fit_s']:.2f} / {row['qr_fit_s']:.2f}")


def projection_cells(cache: Path, shared: Path, seeds: int) -> list[dict[str, Any]]:
    from btel.experiments._common import NordlandData
    from btel.methods.baselines.rabitq import make_rotation

    data = NordlandData(shared / "nordland64", cache, progress=False)
    X, Q = data.features("summer", "hog"), data.features("winter", "hog")
    n = min(len(X), len(Q))
    X = X[:n] / np.linalg.norm(X[:n], axis=1, keepdims=True)
    Q = Q[:n] / np.linalg.norm(Q[:n], axis=1, keepdims=True)
    rows = []
    for D in (104, 536, 2336):
        row: dict[str, Any] = {"map": "nordland summer→winter", "D": D, "d": int(X.shape[1]), "tolerance": 10}
        for rotation in ROTATIONS:
            recalls = []
            for seed in range(seeds):
                R = make_rotation(X.shape[1], D, seed, rotation)
                x, q = R.apply(X), R.apply(Q)
                mean = x.mean(axis=0)
                places = np.argmax((q - mean) @ (x - mean).T, axis=1)
                recalls.append(float(np.mean(np.abs(places - np.arange(n)) <= 10)))
            row[rotation] = recalls
        diff = np.subtract(row["hadamard"], row["qr"])
        row["difference"], row["difference_se"] = float(diff.mean()), float(diff.std(ddof=1) / np.sqrt(len(diff)))
        rows.append(row)
        print(f"rotation alone, Nordland, D = {D:>5}: hadamard {np.mean(row['hadamard']):.4f}  qr "
              f"{np.mean(row['qr']):.4f}  difference {row['difference']:+.4f} ± {row['difference_se']:.4f} "
              f"({seeds} seeds)", flush=True)
    return rows


def cost_cells(widths: tuple[int, ...], max_qr_flops: float) -> list[dict[str, Any]]:
    from btel.datasets import synthetic_route

    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for d in widths:
            route = synthetic_route(500, d, seed=0)
            for b in ("64KB", "1MB"):
                for rotation in ROTATIONS:
                    row: dict[str, Any] = {"d": d, "n_places": 500, "budget": b, "rotation": rotation}
                    model = make_method("rabitq", budget=b, rotation=rotation)
                    D, _ = model.choose_config(500, d, parse_budget(b))
                    if rotation == "qr" and d * D * D > max_qr_flops:
                        row["status"] = f"not run: QR of a {d} × {D} matrix (d·D² = {d * D * D:.1e} flops)"
                        rows.append(row)
                        print(f"d = {d:>6} {b:>5} {rotation:<8} {row['status']}", flush=True)
                        continue
                    start = time.perf_counter()
                    model.fit(route.map)
                    row["fit_s"] = time.perf_counter() - start
                    path = model.save(Path(tmp) / f"m{d}{b}{rotation}.npz")
                    start = time.perf_counter()
                    loaded = btel.load(path)
                    row["load_s"] = time.perf_counter() - start
                    start = time.perf_counter()
                    loaded.predict(route.queries[:1])
                    row["first_query_s"] = time.perf_counter() - start
                    row["recall@0"] = float(np.mean(loaded.predict(route.queries) == np.arange(500)))
                    row["dim"], row["status"] = int(loaded.dim_), "ok"
                    rows.append(row)
                    print(f"d = {d:>6} {b:>5} {rotation:<8} D = {row['dim']:>5}  fit {row['fit_s']:7.2f} s  "
                          f"load {row['load_s']:7.3f} s  first query {row['first_query_s'] * 1e3:8.1f} ms  "
                          f"recall@0 {row['recall@0']:.3f}", flush=True)
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--shared", type=Path, default=HERE.parent.parent / "shared" / "data")
    parser.add_argument("--cache", type=Path, default=HERE / "results" / "cache")
    parser.add_argument("--nordland-seeds", type=int, default=3)
    parser.add_argument("--projection-seeds", type=int, default=20)
    parser.add_argument("--parts", default="recall,projection,cost",
                        help="comma-separated: recall, projection, cost")
    parser.add_argument("--name", default="rabitq_rotation", help="results file name (no extension)")
    parser.add_argument("--max-qr-flops", type=float, default=2e12)
    args = parser.parse_args()
    seeds = 2 if args.quick else args.seeds
    load = [os.getloadavg()[0]]
    started = time.perf_counter()
    parts = set(args.parts.split(","))
    recall, projection, cost = [], [], []
    with limit_threads(1):
        if "recall" in parts:
            recall = recall_cells(args.shared, args.cache, args.quick, seeds, args.nordland_seeds)
        if "projection" in parts and not args.quick:
            projection = projection_cells(args.cache, args.shared, args.projection_seeds)
        if "cost" in parts:
            cost = cost_cells((2048, 8192) if args.quick else (2048, 8192, 16384), args.max_qr_flops)
    load.append(os.getloadavg()[0])
    path = write_results(args.name, {"recall": recall, "projection": projection, "cost": cost, "seeds": seeds,
                                     "nordland_seeds": args.nordland_seeds,
                                     "projection_seeds": args.projection_seeds, "load": load,
                                             "wall_s": time.perf_counter() - started,
                                             "command": " ".join(["python", *sys.argv])})
    print(f"load {load[0]:.1f} → {load[-1]:.1f}; wrote {path}")


if __name__ == "__main__":
    main()
