"""Compare two runs' rows cell by cell, timing cells left out (issue 38's equivalence check).

Usage: python benchmarks/compare_runs.py BEFORE AFTER
BEFORE and AFTER are run folders (metrics.json) or experiment folders (results.json), or folders of
them (each name present in both is compared). Prints one line per file and every differing cell;
exits 1 when a non-timing cell differs.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

#: Cells that hold wall-clock measurements or run metadata, not results.
TIMING = {"fit_time_s", "query_time_s_per_query", "rank_time_s_per_query", "query_latency_s", "fit_s",
          "query_us", "n_threads", "timing_repeats", "cached", "seconds", "timings"}
#: Fields added by this change (new information, absent before): reported, not counted as differences.
ADDED = {"choice", "ground_truth_source", "positive_rule"}


def _rows(path: Path) -> list[dict]:
    data = json.loads(path.read_text())
    return data.get("results") or data.get("rows") or []


def _diff(a: object, b: object, where: str, out: list[str]) -> None:
    if isinstance(a, dict) and isinstance(b, dict):
        for key in sorted(set(a) | set(b)):
            if key in TIMING:
                continue
            if key not in a and key in ADDED:
                continue
            _diff(a.get(key, "<missing>"), b.get(key, "<missing>"), f"{where}.{key}", out)
    elif isinstance(a, list) and isinstance(b, list) and len(a) == len(b):
        for i, (x, y) in enumerate(zip(a, b)):
            _diff(x, y, f"{where}[{i}]", out)
    elif a != b and not (isinstance(a, float) and isinstance(b, float)
                         and abs(a - b) <= 1e-12 * max(1, abs(a))):
        out.append(f"  {where}: {a!r} -> {b!r}")


def compare(before: Path, after: Path) -> int:
    files = sorted(p.relative_to(before) for p in before.rglob("*.json")
                   if p.name in ("metrics.json", "results.json"))
    differing = 0
    for rel in files:
        if not (after / rel).is_file():
            print(f"{rel}: missing after")
            differing += 1
            continue
        a, b = _rows(before / rel), _rows(after / rel)
        out: list[str] = []
        if len(a) != len(b):
            out.append(f"  {len(a)} rows -> {len(b)} rows")
        for i, (x, y) in enumerate(zip(a, b)):
            _diff(x, y, f"row {i} ({x.get('name') or x.get('method')})", out)
        verdict = "same (timing cells aside)" if not out else f"{len(out)} differences"
        print(f"{rel}: {len(a)} rows, {verdict}")
        print("\n".join(out[:40]))
        differing += bool(out)
    return 1 if differing else 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        description=__doc__.splitlines()[0],
        epilog="Exits 1 when a non-timing cell differs, 0 otherwise.")
    parser.add_argument("before", type=Path, metavar="BEFORE",
                        help="run folder (metrics.json), experiment folder (results.json), or a folder of them")
    parser.add_argument("after", type=Path, metavar="AFTER", help="the same, for the run compared against BEFORE")
    args = parser.parse_args(argv)
    return compare(args.before, args.after)


if __name__ == "__main__":
    sys.exit(main())
