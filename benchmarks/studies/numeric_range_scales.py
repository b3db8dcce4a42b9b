"""Every registered method on maps scaled by 1e-44 … 3e37: refused at fit by name, or as good as unscaled.

The evidence behind btel's numeric range rules (``docs/decisions/numeric-range.md``). For each
method, front end (its default, and ``normalize='none'``) and scale s, the map and the queries of
a synthetic route (or Gardens Point NetVLAD with ``--real``) are multiplied by s in float64 and
stored as float32; the model is fitted, saved, loaded and asked ``predict``. A cell is the
recall within 2 places on the scaled data, with the unscaled recall in the first column, or the
btel error that refused it (``refused`` for InvalidDescriptorsError, ``refused (…)`` naming any other),
or in bold any other exception. Writes
``benchmarks/results/study_scales.json`` and prints a markdown table::

    python benchmarks/studies/numeric_range_scales.py            # synthetic route, N = 200, d = 32
    python benchmarks/studies/numeric_range_scales.py --real     # Gardens Point NetVLAD (../shared/data)
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np

SCALES = (1e-44, 1e-38, 1e-20, 1e-15, 1e15, 1e30, 3e37)
RESULTS = Path(__file__).resolve().parents[1] / "results" / "study_scales.json"


def _data(real: bool) -> tuple[np.ndarray, np.ndarray]:
    if real:
        path = Path(__file__).resolve().parents[2].parent / "shared" / "data" / "gardenspoint_netvlad" \
            / "hiddenRepr-GardensPoint.npz"
        with np.load(path) as data:
            return data["hlrTrain"].astype(np.float32), data["hlrTest"].astype(np.float32)
    from btel.datasets import synthetic_route

    route = synthetic_route(n_places=200, dim=32, seed=0)
    return route.map.astype(np.float32), route.queries.astype(np.float32)


def _recall(predicted: np.ndarray) -> float:
    return float((np.abs(predicted - np.arange(predicted.size)) <= 2).mean())


def cell(method: str, params: dict, X: np.ndarray, Q: np.ndarray, scale: float, folder: Path) -> str:
    import btel
    from btel.exceptions import BTELError

    Xs, Qs = ((A.astype(np.float64) * scale).astype(np.float32) for A in (X, Q))
    try:
        model = btel.make_method(method, **params).fit(Xs)
        loaded = btel.load(model.save(folder / "m.btel.npz"))
        return f"{_recall(loaded.predict(Qs)):.2f}"
    except BTELError as exc:
        return "refused" if type(exc).__name__ == "InvalidDescriptorsError" else f"refused ({type(exc).__name__})"
    except Exception as exc:  # noqa: BLE001 - not a named refusal: shown as such
        return f"**{type(exc).__name__}**"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--real", action="store_true",
                        help="Gardens Point NetVLAD instead of a synthetic route")
    parser.add_argument("--methods", default=None, help="comma-separated (default: every registered method)")
    parser.add_argument("--out", default=str(RESULTS))
    args = parser.parse_args()
    warnings.simplefilter("ignore")
    from btel.methods import METHODS

    methods = args.methods.split(",") if args.methods else list(METHODS)
    X, Q = _data(args.real)
    rows = []
    start = time.time()
    with tempfile.TemporaryDirectory() as tmp:
        for method in methods:
            for front in ("default", "none"):
                params = {} if front == "default" else {"normalize": "none"}
                row = {"method": method, "front_end": front,
                       "unscaled": cell(method, params, X, Q, 1.0, Path(tmp))}
                row.update({f"{s:g}": cell(method, params, X, Q, s, Path(tmp)) for s in SCALES})
                rows.append(row)
                print(" | ".join(str(v) for v in row.values()), file=sys.stderr, flush=True)
    header = ["method", "front end", "unscaled", *(f"× {s:g}" for s in SCALES)]
    print("| " + " | ".join(header) + " |")
    print("| " + " | ".join("---" for _ in header) + " |")
    for row in rows:
        print("| " + " | ".join(str(v) for v in row.values()) + " |")
    summary = {"data": "gardens point netvlad" if args.real else "synthetic route N=200 d=32 seed 0",
               "metric": "recall within 2 places", "rows": rows, "seconds": round(time.time() - start, 1),
               "command": " ".join([Path(sys.executable).name, *sys.argv])}
    real_default = args.real and args.out == str(RESULTS)
    out = Path(RESULTS.with_name("study_scales_real.json") if real_default else args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(summary, indent=1) + "\n")
    print(f"\nwritten to {out} ({summary['seconds']} s)", file=sys.stderr)


if __name__ == "__main__":
    main()
