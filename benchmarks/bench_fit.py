"""BTE-C fit time and final objective per solver, against a certified floor and faiss PQ training.

Two shapes (issue #15):

1. **Nordland HOG** — the summer map, N = 3576, d = 3780, c = 1 (d' = d: every bit reads every
   column, the slowest fit of the experiments), front end as the experiments use it (rows L2
   normalised);
2. **synthetic** — ``synthetic_route(8192, 4096)``, c = 0.1 (d' = 410, the default ratio).

For every solver (``BTELocalizer(solver=...)``: 'liblinear' = what btel did before, 'newton',
'lbfgs') the whole ``fit`` is timed (front end, statistics, feature selection, solves) and the
objective the issue names is reported: liblinear's squared-hinge L2-SVM primal objective
``½‖w‖² + ½b² + C Σ max(0, 1 − y(w·x + b))²`` on the standardised columns (bias regularised,
``intercept_scaling = 1``), summed over the bits, recomputed here from the *stored* hyperplanes.

The floor: for each classifier, α = 2C·max(0, 1 − y m) (the KKT map from the primal) is dual
feasible, and the dual objective ``Σα − Σα²/(4C) − ½‖Σ αᵢ yᵢ x̃ᵢ‖²`` of the L2-loss SVM is a lower
bound on the optimum for those columns. The largest bound found (over all solvers' solutions) is
reported as the floor, and each solver's objective as its gap above it. No solver can go below
it; a converged one sits on it.

Peer in the same run: ``faiss.IndexPQ`` training + encoding on the same map (M sub-quantisers of
8 bits). Recall@10 on the queries (winter / the query traverse) is shown beside, as a check that
the models are of the same kind.

    python benchmarks/bench_fit.py                  # both shapes, every solver (~30 min on a quiet 2-core machine)
    python benchmarks/bench_fit.py --shapes synthetic --solvers newton lbfgs
    python benchmarks/bench_fit.py --quick          # N = 1024 subsets: a smoke run

Writes ``benchmarks/results/bench_fit.json`` (and ``bench_fit.png``: objective against time,
one line per solver, from the solvers' per-iteration trace), prints the table with the load
average before and after (``os.getloadavg``: timings on a shared machine are upper bounds), and
rewrites the "Fit speed" section of ``docs/results.md`` (between ``<!-- fit:start -->`` and
``<!-- fit:end -->``; ``--no-docs`` to skip, ``--docs-only`` to rewrite it from the saved JSON).
"""

from __future__ import annotations

import os


import argparse
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

from _common import RESULTS_DIR, write_results  # noqa: E402

SOLVERS = ("liblinear", "newton", "lbfgs")


def load_shape(name: str, quick: bool, data_dir: Path) -> dict[str, Any]:
    """Map, queries and the feature ratio of one shape."""
    if name == "nordland":
        from btel.datasets.nordland import NordlandData

        cache = Path(os.environ.get("BTEL_TEST_CACHE", "/tmp/btel-test-cache"))
        X, Q = NordlandData(data_dir / "nordland64", cache, progress=False).pair("hog")
        if quick:
            X, Q = X[:1024], Q[:1024]
        return {"name": "Nordland HOG summer→winter", "X": X, "Q": Q, "feature_ratio": 1.0}
    from btel.datasets import synthetic_route

    n, dim = (1024, 1024) if quick else (8192, 4096)
    route = synthetic_route(n, dim, seed=0)
    return {"name": f"synthetic route N = {n}, d = {dim}", "X": route.map, "Q": route.queries, "feature_ratio": 0.1}


def certified(model: Any, X: np.ndarray) -> tuple[float, float]:
    """(primal objective, dual lower bound) summed over the bits of a fitted BTE-C model (r = 1).

    Recomputed from the stored hyperplanes: standardised coefficients w·σ, intercept b + w·μ.
    """
    from btel.methods.btel.encoding import encode, n_bits_for
    from btel.learning.linear import ColumnStats, standardised_columns

    Z = model.front_end_.transform(np.asarray(X, dtype=np.float32))
    stats = ColumnStats.of(Z)
    n = Z.shape[0]
    bits = encode(np.arange(n), n_bits_for(n)).astype(np.float64)
    C = 1.0 if model.C is None else float(model.C)
    hp = model.hyperplanes_
    primal = dual = 0.0
    cache: dict[bytes, np.ndarray] = {}
    for k in range(len(hp)):
        cols = np.arange(Z.shape[1]) if hp.columns is None else hp.columns[k if hp.columns.shape[0] > 1 else 0].astype(np.intp)
        key = cols.tobytes()
        if key not in cache:
            cache.clear()
            cache[key] = standardised_columns(Z, cols, stats.mean[cols], stats.scale[cols])
        Xs = cache[key]
        w_std = hp.weights[k].astype(np.float64) * stats.scale[cols]
        b_std = float(hp.bias[k]) + float(hp.weights[k].astype(np.float64) @ stats.mean[cols])
        y = 2.0 * bits[:, k] - 1.0
        r = np.maximum(1.0 - y * (Xs @ w_std + b_std), 0.0)
        primal += 0.5 * (w_std @ w_std + b_std**2) + C * (r @ r)
        alpha = 2.0 * C * r
        v = Xs.T @ (alpha * y)
        dual += alpha.sum() - (alpha @ alpha) / (4.0 * C) - 0.5 * (v @ v + (alpha @ y) ** 2)
    return float(primal), float(dual)


def pq_peer(X: np.ndarray) -> dict[str, Any]:
    """faiss PQ (M × 8 bits, M the largest divisor of d ≤ 32) trained and encoded on the same map."""
    import faiss

    d = X.shape[1]
    M = max(m for m in range(1, 33) if d % m == 0)
    Xc = np.ascontiguousarray(X, dtype=np.float32)
    start = time.perf_counter()
    index = faiss.IndexPQ(d, M, 8)
    index.train(Xc)
    index.add(Xc)
    return {"solver": f"faiss.IndexPQ M={M}×8 bit (train + add)", "fit_s": time.perf_counter() - start,
            "faiss_threads": faiss.omp_get_max_threads()}


def traced_line_search(record):
    """A wrapper of :meth:`btel.learning.primal.Problem.line_search` that calls ``record(iteration, objective)``.

    Newton's method and L-BFGS take one line search per iteration; after it, the objective of the
    group (summed over its classifiers, converged ones at their last value) is recorded — at the
    start point too (w = 0). Installed by monkeypatching, so the library carries no hook.
    """
    from btel.learning.primal import Problem

    original = Problem.line_search

    def line_search(self, V, margins, step_margins, P, cols, t0=1.0):
        t = original(self, V, margins, step_margins, P, cols, t0)
        if not hasattr(self, "_bench_objective"):  # the first step of this group starts from w = 0
            self._bench_objective = self.terms(np.zeros_like(self.Y))[0]
            self._bench_iteration = 0
            record(0, float(self._bench_objective.sum()))
        moved = V + t * P
        self._bench_objective[cols] = 0.5 * (moved * moved).sum(axis=0) + self.terms(margins + t * step_margins, cols)[0]
        self._bench_iteration += 1
        record(self._bench_iteration, float(self._bench_objective.sum()))
        return t

    return original, line_search


def run_solver(shape: dict[str, Any], solver: str, n_jobs: int) -> dict[str, Any]:
    from btel import BTELocalizer
    from btel.learning.primal import Problem

    trace: list[tuple[float, int, float]] = []
    start = time.perf_counter()

    def record(it: int, objective: float) -> None:
        trace.append((time.perf_counter() - start, it, objective))

    original, traced = traced_line_search(record)
    if solver != "liblinear":
        Problem.line_search = traced
    model = BTELocalizer(feature_ratio=shape["feature_ratio"], solver=solver, n_jobs=n_jobs, random_state=0,
                         progress=False)
    import warnings

    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            start, cpu_start = time.perf_counter(), time.process_time()
            model.fit(shape["X"])
            fit_s, cpu_s = time.perf_counter() - start, time.process_time() - cpu_start
    finally:
        Problem.line_search = original
    primal, dual = certified(model, shape["X"])
    pred = model.predict(shape["Q"])
    truth = np.arange(len(shape["Q"]))
    return {"solver": solver, "fit_s": fit_s, "cpu_s": cpu_s, "objective": primal, "dual_bound": dual,
            "solver_objective": model.fit_summary_.objective, "n_classifiers": len(model.hyperplanes_),
            "n_unconverged": model.n_unconverged_, "max_iterations": model.fit_summary_.max_iter_used,
            "n_selected": model.n_selected_, "recall@10": float(np.mean(np.abs(pred - truth) <= 10)),
            "warnings": [str(w.message) for w in caught if "converg" in str(w.message).lower()],
            "trace": trace if len(trace) < 5000 else trace[:: len(trace) // 5000 + 1]}


def plot(path: Path, shapes: list[dict[str, Any]]) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(shapes), figsize=(6.5 * len(shapes), 4.8), squeeze=False)
    for ax, shape in zip(axes[0], shapes):
        floor = shape["floor"]
        for row in shape["rows"]:
            if "objective" not in row:
                ax.axvline(row["fit_s"], color="grey", ls=":", label=row["solver"])
                continue
            # The trace sums the objectives of one group of classifiers: the whole model only when
            # every bit reads every column (d' = d); per-bit groups (d' < d) are traced one by one.
            if row["trace"] and row.get("n_selected") == shape["dim"]:
                t, _, f = zip(*row["trace"])
                ax.plot(t, np.maximum(np.asarray(f) - floor, 1e-9), label=f"{row['solver']} (trace)")
            ax.plot([row["fit_s"]], [max(row["objective"] - floor, 1e-9)], "o",
                    label=f"{row['solver']}: {row['fit_s']:.0f} s, gap {row['objective'] - floor:.3g}")
        ax.set_yscale("log")
        ax.set(xlabel="seconds since fit start", ylabel="objective − floor (summed over bits)",
               title=shape["name"])
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def docs_section(payload: dict[str, Any]) -> str:
    """The "Fit speed" section of docs/results.md from a bench_fit payload."""
    lines = [
        "## Fit speed: solvers (issue #15)",
        "",
        f"`{payload['config']['command'].strip()}` on {payload['machine']['cpu_count']} cores, "
        f"{payload['machine']['date'][:16]}, load average {payload['load_before'][0]:.1f} before and "
        f"{payload['load_after'][0]:.1f} after (1-min; times on a shared machine are upper bounds). BTE-C, whole "
        "`fit` timed; objective = liblinear's squared-hinge L2-SVM primal objective summed over the bits, recomputed "
        "from the stored hyperplanes; floor = the best dual bound (no solver can go below it). Figures: "
        "`benchmarks/results/bench_fit.{json,png}`. CPU seconds (user + system of the process) are given "
        "beside wall seconds; a row marked 'earlier run' was measured by an earlier run of this script "
        "(`--keep-earlier`) and its time is not comparable with the others.",
        "",
        "| shape | solver | fit s | CPU s | objective | above the floor | unconverged | recall@10 |",
        "|---|---|---:|---:|---:|---:|---:|---:|",
    ]
    for shape in payload["shapes"]:
        for r in shape["rows"]:
            if "objective" not in r:
                lines.append(f"| {shape['name']} | {r['solver']} (peer, same run) | {r['fit_s']:.1f} | | | | | |")
                continue
            when = f" (earlier run {r['earlier_run']['date']}, load {r['earlier_run']['load']})" if "earlier_run" in r else ""
            cpu = f"{r['cpu_s']:.1f}" if r.get("cpu_s") is not None else ""
            lines.append(f"| {shape['name']} | {r['solver']}{when} | {r['fit_s']:.1f} | {cpu} | {r['objective']:.3f} | "
                         f"{100 * r['relative_gap']:.2f} % | {r['n_unconverged']}/{r['n_classifiers']} | "
                         f"{r['recall@10']:.3f} |")
        lines.append(f"| {shape['name']} | floor (dual bound) | | | {shape['floor']:.3f} | 0 | | |")
    return "\n".join(lines)


def write_docs_section(text: str) -> Path:
    path = HERE.parent / "docs" / "results.md"
    block = f"<!-- fit:start -->\n{text}\n<!-- fit:end -->"
    current = path.read_text() if path.is_file() else "# Results\n"
    if "<!-- fit:start -->" in current and "<!-- fit:end -->" in current:
        head, rest = current.split("<!-- fit:start -->", 1)
        current = head + block + rest.split("<!-- fit:end -->", 1)[1]
    else:
        current = current.rstrip("\n") + "\n\n" + block + "\n"
    path.write_text(current)
    return path


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--shapes", nargs="+", default=["nordland", "synthetic"], choices=["nordland", "synthetic"])
    parser.add_argument("--solvers", nargs="+", default=list(SOLVERS), choices=list(SOLVERS))
    parser.add_argument("--n-jobs", type=int, default=-1)
    parser.add_argument("--data", type=Path, default=HERE.parent.parent / "shared" / "data")
    parser.add_argument("--quick", action="store_true", help="N = 1024 subsets")
    parser.add_argument("--no-docs", action="store_true", help="do not rewrite docs/results.md")
    parser.add_argument("--docs-only", action="store_true", help="rewrite the docs section from the saved JSON")
    parser.add_argument("--keep-earlier", action="store_true",
                        help="keep the saved rows of solvers not run now (e.g. liblinear, 45 min on Nordland), "
                             "each marked with the date and load of the run that measured it")
    args = parser.parse_args()
    earlier: dict[str, Any] = {}
    if args.keep_earlier and (RESULTS_DIR / "bench_fit.json").is_file():
        import json

        earlier = json.loads((RESULTS_DIR / "bench_fit.json").read_text())
    if args.docs_only:
        import json

        payload = json.loads((RESULTS_DIR / "bench_fit.json").read_text())
        print(f"section written to {write_docs_section(docs_section(payload))}")
        plot(RESULTS_DIR / "bench_fit.png", payload["shapes"])
        return

    load_before = os.getloadavg()
    started = time.perf_counter()
    shapes = []
    for name in args.shapes:
        shape = load_shape(name, args.quick, args.data)
        print(f"\n{shape['name']}: N = {shape['X'].shape[0]}, d = {shape['X'].shape[1]}, c = {shape['feature_ratio']} "
              f"(load average {os.getloadavg()[0]:.1f})", flush=True)
        rows = [pq_peer(shape["X"])]
        print(f"  {rows[0]['solver']}: {rows[0]['fit_s']:.1f} s", flush=True)
        for solver in args.solvers:
            row = run_solver(shape, solver, args.n_jobs)
            row["load_after"] = os.getloadavg()[0]
            rows.append(row)
            print(f"  {solver:<10} {row['fit_s']:8.1f} s (CPU {row['cpu_s']:.1f} s)  objective {row['objective']:12.4f}  dual bound "
                  f"{row['dual_bound']:12.4f}  unconverged {row['n_unconverged']}/{row['n_classifiers']}  "
                  f"iterations ≤ {row['max_iterations']}  recall@10 {row['recall@10']:.3f}  "
                  f"(load {row['load_after']:.1f})", flush=True)
        for previous in (sh for sh in earlier.get("shapes", []) if sh["name"] == shape["name"]):
            for r in previous["rows"]:
                if "objective" in r and r["solver"] not in args.solvers:
                    r.setdefault("earlier_run", {"date": earlier["machine"]["date"][:16],
                                                 "load": round(r.get("load_after", earlier["load_after"][0]), 1)})
                    rows.append(r)
        fitted = [r for r in rows if "objective" in r]
        floor = max(r["dual_bound"] for r in fitted) if fitted else float("nan")
        for r in fitted:
            r["gap_above_floor"] = r["objective"] - floor
            r["relative_gap"] = (r["objective"] - floor) / abs(floor)
        shapes.append({"name": shape["name"], "n_places": int(shape["X"].shape[0]), "dim": int(shape["X"].shape[1]),
                       "feature_ratio": shape["feature_ratio"], "floor": floor, "rows": rows})

    print("\n| shape | solver | fit s | objective | above the floor | unconverged | recall@10 |")
    print("|---|---|---:|---:|---:|---:|---:|")
    for shape in shapes:
        for r in shape["rows"]:
            if "objective" not in r:
                print(f"| {shape['name']} | {r['solver']} (peer) | {r['fit_s']:.1f} | | | | |")
                continue
            print(f"| {shape['name']} | {r['solver']} | {r['fit_s']:.1f} | {r['objective']:.3f} | "
                  f"{100 * r['relative_gap']:.2f} % | {r['n_unconverged']}/{r['n_classifiers']} | {r['recall@10']:.3f} |")
        print(f"| {shape['name']} | floor (dual bound) | | {shape['floor']:.3f} | 0 | | |")
    load_after = os.getloadavg()
    print(f"\nload average before {load_before[0]:.2f}, after {load_after[0]:.2f} (1-min); {os.cpu_count()} cores; "
          f"total {time.perf_counter() - started:.0f} s")
    name = "bench_fit" + ("_quick" if args.quick else "")
    payload = {"config": {**{k: v for k, v in vars(args).items() if k not in ("docs_only", "no_docs")},
                          "data": str(args.data),
                          "command": "python benchmarks/bench_fit.py " + " ".join(sys.argv[1:])},
               "load_before": list(load_before), "load_after": list(load_after), "shapes": shapes}
    path = write_results(name, payload)
    plot(RESULTS_DIR / f"{name}.png", shapes)
    print(f"written to {path} and {name}.png")
    if not args.quick and not args.no_docs:
        import json

        print(f"section written to {write_docs_section(docs_section(json.loads(path.read_text())))}")


if __name__ == "__main__":
    main()
