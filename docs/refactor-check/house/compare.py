"""Compare the before/after files of the house refactor cell by cell, timing excluded.

    python docs/refactor-check/house/compare.py
"""
import json
from pathlib import Path

HERE = Path(__file__).parent
TIMING = {"n_threads", "timing_repeats", "cached", "part_seconds", "command", "date_utc"}


def is_timing(key: str) -> bool:
    return key in TIMING or "time" in key or key.endswith(("_s", "_us")) or key == "seconds"


def flat(obj, path=""):
    if isinstance(obj, dict):
        for k, v in obj.items():
            yield from flat(v, f"{path}.{k}")
    elif isinstance(obj, list):
        for i, v in enumerate(obj):
            yield from flat(v, f"{path}[{i}]")
    else:
        yield path, obj


for name in ("beyond-quick", "codes-quick", "demo"):
    before = json.loads((HERE / f"{name}-before.json").read_text())
    after = json.loads((HERE / f"{name}-after.json").read_text())
    if "rows" in before:
        before, after = before["rows"], after["rows"]
        print(f"{name}: {len(before)} rows before, {len(after)} after", end="; ")
    a, b = dict(flat(before)), dict(flat(after))
    keys = [k for k in set(a) | set(b)
            if not any(is_timing(part.split("[")[0]) for part in k.split(".")) and not k.startswith(".run.")]
    differ = sorted(k for k in keys if a.get(k) != b.get(k))
    print(f"{len(keys)} cells compared, {len(differ)} differ {differ[:5]}")
