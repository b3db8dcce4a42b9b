"""Helpers shared by the benchmark scripts: machine description and result files."""

from __future__ import annotations

import datetime as dt
import json
import os
import platform
import sys
from pathlib import Path
from typing import Any

RESULTS_DIR = Path(__file__).resolve().parent / "results"


def machine() -> dict[str, Any]:
    """What the figures were measured on."""
    import numpy
    import sklearn

    import btel

    info = {
        "date": dt.datetime.now().isoformat(timespec="seconds"),
        "python": sys.version.split()[0],
        "platform": platform.platform(),
        "cpu_count": os.cpu_count(),
        "btel": btel.__version__,
        "numpy": numpy.__version__,
        "scikit-learn": sklearn.__version__,
    }
    try:
        import faiss

        info["faiss"] = faiss.__version__
    except ImportError:  # pragma: no cover
        pass
    return info


def write_results(name: str, payload: dict[str, Any]) -> Path:
    """Write ``benchmarks/results/<name>.json`` (machine info included) and return its path."""
    RESULTS_DIR.mkdir(parents=True, exist_ok=True)
    path = RESULTS_DIR / f"{name}.json"
    path.write_text(json.dumps({"machine": machine(), **payload}, indent=2, default=float) + "\n")
    return path


#: Recall tolerance of each key recall of ``btel experiment frontier``'s maps.
TOLERANCE = {"recall@0": 0, "recall@2": 2, "recall@10": 10}
_HERE = Path(__file__).resolve().parent


def add_data_arguments(parser: Any) -> None:
    """``--data`` (the Nordland folder) and ``--cache`` (its HOG features) of the frontier's maps."""
    parser.add_argument("--data", type=Path, default=_HERE.parent.parent / "shared" / "data" / "nordland64")
    parser.add_argument("--cache", type=Path, default=RESULTS_DIR / "cache")


def frontier_maps(args: Any, quick: bool = False) -> list:
    """``btel experiment frontier``'s maps: [(base, X, Q)], base holding ``dataset`` and ``key``."""
    from btel.experiments._common import NordlandData
    from btel.experiments.frontier import _maps

    return _maps(NordlandData(args.data, args.cache, progress=False), quick)


def cone_direction(X: Any, seed: int = 9) -> Any:
    """A seeded direction as long as the mean row of ``X``: adding ``offset`` × it to every map and query
    row puts the rows in a cone (cone ratio ≈ 0.24 → 0.73 → 0.84 → 0.95 at offsets 0, 1, 1.5, 3)."""
    import numpy as np

    direction = np.random.default_rng(seed).normal(size=X.shape[1]).astype(np.float32)
    return direction * (np.linalg.norm(X, axis=1).mean() / np.linalg.norm(direction))


def snippet_order(n_rows: int, length: int) -> Any:
    """Row order of a route cut into snippets of ``length`` consecutive rows, the snippets shuffled (seed =
    length; the last ``n_rows`` mod ``length`` rows are left out)."""
    import numpy as np

    snippets = np.arange(n_rows // length * length).reshape(-1, length)
    return np.concatenate(snippets[np.random.default_rng(length).permutation(len(snippets))])


def key_recall(pred: Any, key: str) -> float:
    """Share of queries i whose predicted place lies within the key's tolerance of place i."""
    import numpy as np

    pred = np.asarray(pred)
    return float(np.mean(np.abs(pred - np.arange(pred.shape[0])) <= TOLERANCE[key]))


def paired_difference(a: list[float], b: list[float]) -> dict[str, Any]:
    """``a`` − ``b`` paired by seed: ``{"difference_mean", "difference_se"}`` (se None with one pair).

    The same computation as the frontier's auto − LSH column (:func:`btel.experiments.frontier.paired_difference`).
    """
    from btel.experiments.frontier import paired_difference as frontier_paired

    paired = frontier_paired({"value": a[0], "seed_values": list(a)}, {"value": b[0], "seed_values": list(b)})
    return {"difference_mean": paired["diff"], "difference_se": paired["diff_se"]}


def signed(row: dict[str, Any]) -> str:
    """"+0.012 ± 0.008" from a row holding ``difference_mean`` and ``difference_se``."""
    se = row["difference_se"]
    return f"{row['difference_mean']:+.3f}" + ("" if se is None else f" ± {se:.3f}")


def peak_rss() -> int:
    """Peak resident bytes of this process image: VmHWM on Linux. ``ru_maxrss`` survives exec, so in a
    child process it includes the parent's peak (a worker started by a pytest process that once held
    over 1 GiB began above a 1 GiB limit); elsewhere ru_maxrss."""
    import resource

    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) * 1024
    except OSError:  # not Linux
        pass
    scale = 1 if sys.platform == "darwin" else 1024
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * scale
