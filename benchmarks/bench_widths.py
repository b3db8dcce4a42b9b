"""Descriptor widths: fit, save, load and first-query cost of each method ``auto`` can choose by N, d, budget.

Methods: ``lsh``, ``lsh`` on shrinkage-whitened rows, periodic ``btel-codes``, ``bruteforce`` (plain and
shrinkage-whitened), ``pq``, ``opq``, ``rabitq``, and ``auto`` itself. Maps: N rows sharing a common
direction and a low-rank part plus noise (float32), for every d of ``--dims`` and N of ``--rows``;
queries: 200 map rows plus noise (near duplicates, cosine ≈ 0.93 to their row). Budgets: ``--budgets``.

Each cell runs in two forked children on one thread (OpenBLAS, OpenMP): the first fits and saves the
model, the second — forked from the parent, which holds only the data and the imports (the parent
fits, saves and loads a tiny model of every method first) — loads it and answers one query
(the first answer), then 10 single queries (the median is "next"), then the 200 queries (recall@0).
"resident" is the second child's resident-memory growth from before the load to after the first query
(measured after it has loaded and queried a tiny model of the same method, so that the pages of code
both run are already in).
A child that runs longer than ``--timeout`` seconds is stopped and its cell marked; a method that
was stopped is not run again at that or a larger N, d and budget (they cost at least as much).
Figures are from a shared machine: the load average is recorded beside them.

    python benchmarks/bench_widths.py                      # the default grid, about 10 min
    python benchmarks/bench_widths.py --rows 500 --dims 256,2048 --timeout 20   # a quick look
    python benchmarks/bench_widths.py --doc-only     # docs/widths.md again from the last results

Writes ``benchmarks/results/bench_widths.json`` and the tables of ``docs/widths.md`` (regenerated).
"""

from __future__ import annotations

import os

for _name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):  # before numpy loads
    os.environ[_name] = "1"

import argparse  # noqa: E402
import multiprocessing  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import Any  # noqa: E402

import numpy as np  # noqa: E402

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

from _common import write_results  # noqa: E402

from btel.core.storage import parse_budget  # noqa: E402

#: name → (registered method, parameters)
METHODS: dict[str, tuple[str, dict[str, Any]]] = {
    "lsh": ("lsh", {}),
    "lsh+shrink": ("lsh", {"whiten": "shrink"}),
    "btel-codes": ("btel-codes", {"code": "periodic"}),
    "bruteforce": ("bruteforce", {}),
    "bruteforce+shrink": ("bruteforce", {"whiten": "shrink"}),
    "pq": ("pq", {}),
    "opq": ("opq", {}),
    "rabitq": ("rabitq", {}),
    "auto": ("auto", {}),
}
N_QUERIES = 200
DOC = HERE.parent / "docs" / "widths.md"


def make_data(n_rows: int, d: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Rows = common direction + low-rank part + noise; queries = the first 200 rows plus noise."""
    rng = np.random.default_rng(seed)
    X = rng.standard_normal((n_rows, d), dtype=np.float32)
    X *= 0.6
    X += rng.standard_normal(d, dtype=np.float32)
    factors = rng.standard_normal((n_rows, 64), dtype=np.float32)
    low_rank = factors @ rng.standard_normal((64, d), dtype=np.float32)
    X += 0.075 * low_rank
    Q = X[:N_QUERIES] + 0.5 * rng.standard_normal((min(N_QUERIES, n_rows), d), dtype=np.float32)
    return X, Q


def resident_bytes() -> int:
    """This process' resident memory (VmRSS)."""
    with open("/proc/self/status") as status:
        for line in status:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) * 1024
    return 0


def fit_and_save(name: str, budget: str, X: np.ndarray, path: str) -> dict[str, Any]:
    from btel.exceptions import BudgetTooSmallError
    from btel.methods import make_method

    method, params = METHODS[name]
    start = time.perf_counter()
    try:
        model = make_method(method, budget=budget, **params).fit(X)
    except BudgetTooSmallError as exc:
        return {"status": "too small", "minimum": exc.minimum, "fit_s": time.perf_counter() - start}
    fit = time.perf_counter() - start
    start = time.perf_counter()
    model.save(path)
    chosen = getattr(model, "choice_", None)
    # What the planner chose, as `btel info` prints it: the fitted state's scalars.
    state = model._fitted_state() if callable(getattr(model, "_fitted_state", None)) else {}
    choices = ", ".join(f"{k}={v}" for k, v in state.items()
                        if isinstance(v, (bool, int, str)) and k not in ("n_features_in", "n_places"))
    return {"status": "ok", "fit_s": fit, "save_s": time.perf_counter() - start, "stored": int(model.nbytes),
            "file": os.path.getsize(path), "summary": model.summary()[:160], "chosen_at_fit": choices[:160],
            "chose": None if chosen is None else f"{chosen['method']} {chosen['params'] or ''}".strip()}


def load_and_query(path: str, Q: np.ndarray, warm: str | None = None) -> dict[str, Any]:
    import btel

    if warm is not None:  # a tiny model of the same method first: the code load and search run is in memory
        tiny = btel.load(warm)
        tiny.predict(np.ones((1, tiny.n_features_in_), dtype=np.float32))
    before = resident_bytes()
    start = time.perf_counter()
    model = btel.load(path)
    load = time.perf_counter() - start
    start = time.perf_counter()
    model.predict(Q[:1])
    first = time.perf_counter() - start
    resident = resident_bytes() - before
    single = []
    for i in range(1, 11):
        start = time.perf_counter()
        model.predict(Q[i : i + 1])
        single.append(time.perf_counter() - start)
    recall = float(np.mean(model.predict(Q) == np.arange(Q.shape[0])))
    return {"load_s": load, "first_ms": first * 1e3, "next_ms": float(np.median(single)) * 1e3,
            "resident": resident, "recall": recall}


def _child(target, args, pipe) -> None:
    try:
        pipe.send(target(*args))
    except Exception as exc:  # reported, not raised: one failing cell must not stop the grid
        pipe.send({"status": f"error: {type(exc).__name__}: {str(exc)[:200]}"})


def in_child(target, args, timeout: float) -> dict[str, Any]:
    """``target(*args)`` in a forked child; ``{"status": "timeout"}`` when it runs past ``timeout`` s."""
    context = multiprocessing.get_context("fork")
    receive, send = context.Pipe(duplex=False)
    child = context.Process(target=_child, args=(target, args, send))
    child.start()
    send.close()
    if receive.poll(timeout):
        result = receive.recv()
    else:
        child.kill()
        result = {"status": "timeout"}
    child.join()
    return result


def cell_text(row: dict[str, Any]) -> list[str]:
    """The table cells of one measured row."""
    status = row["status"]
    if status != "ok":
        text = {"too small": f"does not fit (needs ≥ {row.get('minimum') or '?'} B)",
                "timeout": f"stopped after {row.get('timeout', 0):.0f} s",
                "skipped": "not run (stopped at a smaller N, d or budget)"}.get(status, status)
        return [text] + [""] * 7
    return [f"{row['stored'] / 1e3:,.0f}", f"{row['fit_s']:.2f}", f"{row['save_s']:.3f}",
            f"{row['load_s']:.3f}" if "load_s" in row else "–",
            f"{row['first_ms']:.1f}" if "first_ms" in row else "–",
            f"{row['next_ms']:.2f}" if "next_ms" in row else "–",
            f"{row['resident'] / 1e6:.1f}" if "resident" in row else "–",
            f"{row['recall']:.2f}" if "recall" in row else "–"]


def growth(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Per method, N and budget: the fit and load time ratios between the two widest d measured, and their
    exponents (log2 of the ratio per doubling of d: 1 is linear in d, 2 quadratic). Times under 20 ms are
    left out."""
    by_key: dict[tuple, dict[int, dict[str, Any]]] = {}
    for row in rows:
        if row["status"] == "ok":
            by_key.setdefault((row["method"], row["n_rows"], row["budget"]), {})[row["d"]] = row
    out = []
    for (method, n_rows, budget), cells in sorted(by_key.items()):
        dims = sorted(cells)
        if len(dims) < 2:
            continue
        a, b = cells[dims[-2]], cells[dims[-1]]
        steps = np.log2(dims[-1] / dims[-2])
        ratios = {key[:-2]: b[key] / a[key] for key in ("fit_s", "load_s")
                  if key in a and key in b and a[key] > 0.02 and b[key] > 0}
        if ratios:
            out.append({"method": method, "n_rows": n_rows, "budget": budget, "dims": dims[-2:],
                        "ratios": ratios,
                        "exponents": {k: float(np.log2(r) / steps) for k, r in ratios.items()}})
    return out


def write_doc(rows: list[dict[str, Any]], meta: dict[str, Any]) -> None:
    head = ("| d | budget | method | stored KB | fit s | save s | load s | first query ms | next query ms | "
            "resident MB | recall@0 |")
    rule = "| ---: | --- | --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |"
    # Front matter: the site's navigation and table of contents hidden, so the wide tables fit the page.
    out = ["---", "hide:", "  - navigation", "  - toc", "---", "", "# Descriptor widths: what each method costs as d grows", "",
           f"Generated by `benchmarks/bench_widths.py`, run as `{meta['command']}`; do not edit by hand. "
           f"Measured {meta['date']} on one thread of a shared machine (load average "
           f"{meta['load'][0]:.1f} at the start, {meta['load_end'][0]:.1f} at the end; "
           f"{meta['seconds']:.0f} s in all). Each cell: fit and "
           "save in "
           "one forked process, load and queries in a fresh one. *first query* is the first `predict` of one "
           "query after `btel.load` (lazy caches included); *next* the median of the next 10 single queries; "
           "*resident* the loading process' resident-memory growth from before the load to after the first "
           "query (after a tiny model of the same method was loaded and queried); recall@0 of 200 "
           "near-duplicate "
           "queries (map rows plus noise). Cells that ran past the "
           f"time limit ({meta['timeout']:.0f} s) were stopped.", ""]
    for n_rows in sorted({r["n_rows"] for r in rows}):
        out += [f"## N = {n_rows:,}", "", head, rule]
        for row in rows:
            if row["n_rows"] == n_rows:
                label = row["method"] + (f" → {row['chose']}" if row.get("chose") else "")
                cells = " | ".join(cell_text(row))
                out.append(f"| {row['d']:,} | {row['budget']} | {label} | {cells} |")
        out.append("")
    trends = growth(rows)
    if trends:
        lines = []
        for t in trends:
            ratios = "; ".join(f"{k} ×{r:.1f} (exponent {t['exponents'][k]:.1f})"
                               for k, r in t["ratios"].items())
            widths = f"d {t['dims'][0]:,} → {t['dims'][1]:,}"
            lines.append(f"| {t['method']} | {t['n_rows']:,} | {t['budget']} | {widths} | {ratios} |")
        steep = [f"{t['method']} (N = {t['n_rows']:,}, {t['budget']})" for t in trends
                 if max(t["exponents"].values()) >= 1.8]
        out += ["## Growth in d", "",
                "Time ratio between the two widest d each method ran at (same N and budget), and its "
                "exponent (log2 of the ratio per doubling of d: 1 = linear, 2 = quadratic). Ratios of times "
                "below 20 ms are left out.", "", "| method | N | budget | widths | fit, load |",
                "| --- | ---: | --- | --- | --- |", *lines, "",
                f"Exponent 1.8 or more (about d² or worse): {'; '.join(steep) if steep else 'none'}.", ""]
        # A budget planner may choose another configuration at the wider d (PQ buying a PCA projection, say):
        # the two models' own summaries say whether the ratio compares like with like.
        for t in trends:
            if max(t["exponents"].values()) < 1.8:
                continue
            out.append(f"{t['method']} at N = {t['n_rows']:,}, {t['budget']}, as each model describes itself:")
            out.append("")
            for d in t["dims"]:
                row = next(r for r in rows if (r["method"], r["n_rows"], r["budget"], r["d"])
                           == (t["method"], t["n_rows"], t["budget"], d))
                described = row.get("summary") or f"chosen at fit: {row.get('chosen_at_fit') or '–'}"
                out.append(f"- d = {d:,}: fit {row['fit_s']:.2f} s — {described}")
            out.append("")
    DOC.parent.mkdir(parents=True, exist_ok=True)
    DOC.write_text("\n".join(out))


def warm_up(names: list[str], folder: str) -> dict[str, str]:
    """Import everything fitting, saving, loading and answering need, in the parent the children are forked
    from: their times are then the model's, not the interpreter's imports. Returns the tiny models' paths."""
    X, Q = make_data(64, 32)
    paths = {}
    for name in names:
        path = os.path.join(folder, f"warm-{name}.npz")
        if fit_and_save(name, "1MB", X, path)["status"] == "ok":
            load_and_query(path, Q)
            paths[name] = path
    return paths


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rows", default="500,10000")
    parser.add_argument("--dims", default="256,2048,8192,16384")
    parser.add_argument("--budgets", default="64KB,1MB,16MB")
    parser.add_argument("--methods", default=",".join(METHODS))
    parser.add_argument("--timeout", type=float, default=20.0, help="seconds per child")
    parser.add_argument("--no-doc", action="store_true", help="do not rewrite docs/widths.md")
    parser.add_argument("--doc-only", action="store_true", help="docs/widths.md from the last results")
    args = parser.parse_args()
    if args.doc_only:
        import json

        results = json.loads((HERE / "results" / "bench_widths.json").read_text())
        write_doc(results["rows"], results)
        print(f"wrote {DOC}")
        return
    start, load = time.time(), os.getloadavg()
    rows: list[dict[str, Any]] = []
    stopped: list[tuple[str, int, int, int]] = []   # (method, N, d, budget bytes) of cells that ran too long
    with tempfile.TemporaryDirectory() as tmp:
        warm = warm_up(args.methods.split(","), tmp)
        for n_rows in (int(v) for v in args.rows.split(",")):
            for d in (int(v) for v in args.dims.split(",")):
                X, Q = make_data(n_rows, d)
                for budget in args.budgets.split(","):
                    for name in args.methods.split(","):
                        row: dict[str, Any] = {"method": name, "n_rows": n_rows, "d": d, "budget": budget}
                        size = parse_budget(budget)
                        if any(m == name and n_rows >= n and d >= w and size >= b for m, n, w, b in stopped):
                            rows.append({**row, "status": "skipped"})
                            continue
                        path = os.path.join(tmp, "model.npz")
                        row.update(in_child(fit_and_save, (name, budget, X, path), args.timeout))
                        if row["status"] == "ok":
                            row.update(in_child(load_and_query, (path, Q, warm.get(name)), args.timeout))
                        if row["status"] == "timeout":
                            row["timeout"] = args.timeout
                            stopped.append((name, n_rows, d, size))
                        rows.append(row)
                        print(f"N {n_rows:>6} d {d:>6} {budget:>5} {name:<18} " + " | ".join(cell_text(row))
                              + f"  [{time.time() - start:.0f} s]", flush=True)
                del X, Q
    meta = {"command": " ".join(["python benchmarks/bench_widths.py", *sys.argv[1:]]),
            "date": time.strftime("%Y-%m-%d"), "load": load, "load_end": os.getloadavg(),
            "seconds": time.time() - start, "timeout": args.timeout}
    out = write_results("bench_widths", {"rows": rows, **meta})
    if not args.no_doc:
        write_doc(rows, meta)
    print(f"wrote {out}{'' if args.no_doc else f' and {DOC}'} ({time.time() - start:.0f} s)")


if __name__ == "__main__":
    main()
