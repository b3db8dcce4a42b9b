"""First answer: ``btel localize MODEL q.npy -o out.csv`` against a faiss script doing the same job.

Each job runs in a fresh interpreter (a cold start, warm file cache: one untimed run each first):
load the model or index, read the queries, answer them (k = 1), write the ``query,prediction`` CSV.
The faiss script (:data:`FAISS_SCRIPT`) reads an index of the same kind as the btel method:

============ ======================================================================================
btel method  faiss peer
============ ======================================================================================
bruteforce   ``IndexFlatL2`` over the map rows
pq           btel's own ``IndexPQ`` (same M, nbits, codes; btel's PCA as an ``IndexPreTransform``)
lsh          ``IndexLSH`` with the same number of bits, trained on the map (rotation, thresholds)
btel-codes   ``IndexFlatIP`` over the map rows (the reference the codes are held to)
============ ======================================================================================

The two commands of a method alternate, ``--repeats`` times each, with one thread for both
(``OMP_NUM_THREADS=1`` …); the ratio of their medians is the figure (target ≤ 2). Python's bytecode
cache is on (in a temporary ``PYTHONPYCACHEPREFIX``), as for an installed package: without it every
run would compile btel's modules again. The load
average before and after is printed and stored: the machine is shared, so compare ratios from one
run, not seconds across runs. ``python -c pass`` and ``python -c "import numpy, faiss"`` are timed
in the same run for scale.

    python benchmarks/bench_first_answer.py                 # synthetic route N = 10,000, d = 256
    python benchmarks/bench_first_answer.py --real          # plus Gardens Point NetVLAD (200 × 500)
    python benchmarks/bench_first_answer.py --before ../main/src   # also another btel tree, same run

``--before SRC`` also times the same ``btel localize`` with the btel package under SRC (an older
checkout reading the same model files: the figures before a change), in the same alternation.

Each row also has the import time of ``btel.load(MODEL)`` + ``predict`` in a fresh interpreter (the
sum of ``python -X importtime``'s self times, minimum of 3) and the packages it imported, for this
tree and the ``--before`` one.

Writes ``benchmarks/results/bench_first_answer.json``.
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
from _common import write_results  # noqa: E402

SRC = HERE.parent / "src"
GARDENS_POINT = HERE.parents[1] / "shared" / "data" / "gardenspoint_netvlad" / "hiddenRepr-GardensPoint.npz"

#: The peer: what a faiss user writes for the same job.
FAISS_SCRIPT = """\
import csv, sys
import faiss, numpy as np
index = faiss.read_index(sys.argv[1])
Q = np.ascontiguousarray(np.load(sys.argv[2]), dtype=np.float32)
_, rows = index.search(Q, 1)
with open(sys.argv[3], "w", newline="") as fh:
    writer = csv.writer(fh)
    writer.writerow(["query", "prediction"])
    for i, p in enumerate(rows[:, 0].tolist()):
        writer.writerow([i, p])
print(f"{len(rows)} predictions written to {sys.argv[3]}")
"""

METHODS = ("bruteforce", "pq", "lsh", "btel-codes")
ONE_THREAD = {name: "1" for name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")}


def peer_index(name: str, model, X: np.ndarray):
    """The faiss index a faiss user would build for the job ``name`` does (module docstring)."""
    import faiss

    d = X.shape[1]
    if name == "bruteforce":
        index = faiss.IndexFlatL2(d)
    elif name == "btel-codes":
        index = faiss.IndexFlatIP(d)
    elif name == "lsh":
        index = faiss.IndexLSH(d, int(model.n_bits_), True, True)
        index.train(X)
    elif name == "pq":
        index = model._index  # btel's own trained IndexPQ: the same codes, searched directly
        if model.projection_ is not None:
            transform = faiss.LinearTransform(d, model.projection_.shape[1], False)
            faiss.copy_array_to_vector(np.ascontiguousarray(model.projection_.T).ravel(), transform.A)
            transform.is_trained = True
            index = faiss.IndexPreTransform(transform, index)
        return index
    else:
        raise ValueError(name)
    index.add(X)
    return index


def timed(argv: list[str], env: dict[str, str]) -> float:
    start = time.perf_counter()
    subprocess.run(argv, env=env, check=True, stdout=subprocess.DEVNULL)
    return time.perf_counter() - start


def bench_env(src: Path, folder: Path) -> dict[str, str]:
    """One thread, btel from ``src``, bytecode cached under ``folder`` (as an installed package has it)."""
    env = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}
    return {**env, **ONE_THREAD, "PYTHONPATH": str(src), "PYTHONPYCACHEPREFIX": str(folder / "pycache")}


_LOAD_AND_PREDICT = "import sys, numpy as np, btel\nbtel.load(sys.argv[1]).predict(np.load(sys.argv[2]))"
_WATCHED = {"sklearn", "scipy", "ruptures", "joblib", "tqdm", "faiss", "threadpoolctl", "cv2", "skimage"}


def import_time(model: Path, queries: Path, env: dict[str, str]) -> tuple[float, list[str]]:
    """(ms, watched packages imported) of load + predict: ``-X importtime`` self times summed, min of 3."""
    best: tuple[float, list[str]] | None = None
    for _ in range(3):
        argv = [sys.executable, "-X", "importtime", "-c", _LOAD_AND_PREDICT, str(model), str(queries)]
        err = subprocess.run(argv, env=env, check=True, capture_output=True, text=True).stderr
        rows = [line.split("|") for line in err.splitlines()
                if line.startswith("import time:") and "self [us]" not in line]
        total = sum(int(r[0].split(":")[1]) for r in rows) / 1e3
        if best is None or total < best[0]:
            best = (total, sorted({r[2].strip().split(".")[0] for r in rows} & _WATCHED))
    return best


def run_map(label: str, X: np.ndarray, Q: np.ndarray, budget: str, repeats: int, folder: Path,
            before: Path | None = None) -> list[dict]:
    import faiss

    from btel import make_method

    env = bench_env(SRC, folder)
    q_path = folder / f"{label}_q.npy"
    np.save(q_path, Q)
    script = folder / "faiss_localize.py"
    script.write_text(FAISS_SCRIPT)
    rows = []
    for name in METHODS:
        model = make_method(name, **({} if name == "bruteforce" else {"budget": budget}))
        model = model.set_params(**{k: v for k, v in {"n_jobs": 1, "progress": False}.items()
                                    if k in model.get_params()}).fit(X)
        model_path = model.save(folder / f"{label}_{name}.npz")
        index_path = folder / f"{label}_{name}.faiss"
        faiss.write_index(peer_index(name, model, X), str(index_path))
        out = folder / "out.csv"
        btel_cmd = [sys.executable, "-m", "btel.cli", "localize", str(model_path), str(q_path), "-o",
                    str(out), "--overwrite"]
        faiss_cmd = [sys.executable, str(script), str(index_path), str(q_path), str(out)]
        load = os.getloadavg()
        old_env = bench_env(before, folder / "before") if before else None
        timed(btel_cmd, env), timed(faiss_cmd, env)  # warm the file cache
        if old_env:
            timed(btel_cmd, old_env)
        btel_s, faiss_s, old_s = [], [], []
        for _ in range(repeats):
            btel_s.append(timed(btel_cmd, env))
            faiss_s.append(timed(faiss_cmd, env))
            if old_env:
                old_s.append(timed(btel_cmd, old_env))
        row = {"map": label, "method": name, "n_places": int(X.shape[0]), "d": int(X.shape[1]),
               "queries": int(Q.shape[0]), "budget": None if name == "bruteforce" else budget,
               "model_bytes": int(model.nbytes), "btel_median_s": statistics.median(btel_s),
               "faiss_median_s": statistics.median(faiss_s), "btel_s": btel_s, "faiss_s": faiss_s,
               "load_before": list(load), "load_after": list(os.getloadavg())}
        row["ratio"] = row["btel_median_s"] / row["faiss_median_s"]
        row["import_ms"], row["imports"] = import_time(model_path, q_path, env)
        if old_env:
            row["before_import_ms"], row["before_imports"] = import_time(model_path, q_path, old_env)
        if old_s:
            row["before_s"], row["before_median_s"] = old_s, statistics.median(old_s)
            row["before_ratio"] = row["before_median_s"] / row["faiss_median_s"]
        rows.append(row)
        before_text = f"{row['before_median_s']:8.3f} {row['before_ratio']:6.2f}" if old_s else ""
        print(f"{label:<14} {name:<11} {row['btel_median_s']:8.3f} {row['faiss_median_s']:8.3f} "
              f"{row['ratio']:6.2f} {before_text}  {load[0]:.2f} → {row['load_after'][0]:.2f}", flush=True)
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("--places", type=int, default=10_000)
    parser.add_argument("--dim", type=int, default=256)
    parser.add_argument("--queries", type=int, default=100)
    parser.add_argument("--budget", default="64KB")
    parser.add_argument("--real", action="store_true", help="also Gardens Point NetVLAD (../shared/data)")
    parser.add_argument("--before", type=Path, default=None, help="another btel source tree, timed alike")
    args = parser.parse_args()
    from btel.datasets import synthetic_route

    env = bench_env(SRC, Path(tempfile.gettempdir()))
    scale = {"python -c pass": [sys.executable, "-c", "pass"],
             "import numpy, faiss": [sys.executable, "-c", "import numpy, faiss"]}
    scale_s = {}
    for key, argv in scale.items():
        timed(argv, env)
        scale_s[key] = statistics.median(timed(argv, env) for _ in range(args.repeats))
    print("  ".join(f"{k}: {v:.3f} s" for k, v in scale_s.items()))
    extra = f" {'before s':>8} {'ratio':>6}" if args.before else ""
    print(f"{'map':<14} {'method':<11} {'btel s':>8} {'faiss s':>8} {'ratio':>6}{extra}  load")
    route = synthetic_route(args.places, args.dim, seed=0)
    queries = route.queries[np.arange(args.queries) % route.queries.shape[0]]
    with tempfile.TemporaryDirectory() as tmp:
        rows = run_map("synthetic", route.map, queries, args.budget, args.repeats, Path(tmp), args.before)
        if args.real:
            with np.load(GARDENS_POINT) as data:
                X, Q = data["hlrTrain"].astype(np.float32), data["hlrTest"].astype(np.float32)
            rows += run_map("gardens-point", X, Q, "16KB", args.repeats, Path(tmp), args.before)
    path = write_results("bench_first_answer", {"rows": rows, "scale_s": scale_s, "target_ratio": 2.0,
                                                "command": " ".join(["python", *sys.argv])})
    print(f"written {path}")


if __name__ == "__main__":
    main()
