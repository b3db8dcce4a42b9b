"""Start-up time: ``import btel`` and ``btel --help`` in a fresh interpreter, against their peers.

Each command runs in its own subprocess (a cold interpreter, warm file cache: one untimed run
first), ``--repeats`` times; the median wall time is reported. The peers measured in the same run
put the figures in proportion: ``python -c pass`` (the interpreter alone) and ``import sklearn``
(what ``import btel`` used to pay before its names were imported lazily).

    python benchmarks/bench_import.py            # 7 repeats
    python benchmarks/bench_import.py --repeats 15

Writes benchmarks/results/bench_import.json.
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import write_results  # noqa: E402

SRC = Path(__file__).resolve().parents[1] / "src"

COMMANDS = {
    "python -c pass": [sys.executable, "-c", "pass"],
    "import sklearn": [sys.executable, "-c", "import sklearn.base"],
    "import btel": [sys.executable, "-c", "import btel"],
    "btel --help": [sys.executable, "-m", "btel.cli", "--help"],
    "btel train --help": [sys.executable, "-m", "btel.cli", "train", "--help"],
    "import btel; btel.BTELocalizer": [sys.executable, "-c", "import btel; btel.BTELocalizer"],
}


def time_command(argv: list[str], repeats: int) -> list[float]:
    """Wall seconds of ``repeats`` runs of ``argv`` (after one untimed warm-up run)."""
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(SRC), os.environ.get("PYTHONPATH", "")])}
    subprocess.run(argv, env=env, check=True, capture_output=True)
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        subprocess.run(argv, env=env, check=True, capture_output=True)
        times.append(time.perf_counter() - start)
    return times


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=7)
    args = parser.parse_args()
    rows = {}
    for name, argv in COMMANDS.items():
        times = time_command(argv, args.repeats)
        rows[name] = {"median_s": statistics.median(times), "min_s": min(times), "max_s": max(times),
                      "repeats": args.repeats}
    base = rows["python -c pass"]["median_s"]
    sk = rows["import sklearn"]["median_s"]
    print(f"{'command':<34} {'median s':>9} {'min s':>7} {'max s':>7} {'÷ sklearn':>10}")
    for name, r in rows.items():
        r["ratio_to_import_sklearn"] = r["median_s"] / sk
        r["over_bare_python_s"] = r["median_s"] - base
        print(f"{name:<34} {r['median_s']:9.3f} {r['min_s']:7.3f} {r['max_s']:7.3f} {r['ratio_to_import_sklearn']:10.2f}")
    path = write_results("bench_import", {"rows": rows, "target_s": 0.5})
    print(f"written {path}")


if __name__ == "__main__":
    main()
