"""Single-query latency of btel-codes against faiss.IndexFlatIP: medians over repeated runs of two versions.

Each input is a results file of ``benchmarks/bench_codes.py`` (``--quick``: synthetic N = 10⁴, 10⁵;
``--real-only``: Gardens Point and Nordland), run several times per version of the code on the
same shared machine. Every run states its ratios against flat search timed in the same process
(one thread each), so runs at different loads can be compared; this takes, per version and row,
the median of those ratios and of the absolute medians, with the loads the runs saw.

    python benchmarks/compare_codes_single.py --label before a.json b.json --label after c.json d.json

Writes ``benchmarks/results/bench_codes_single_query.json``.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections import defaultdict
from pathlib import Path
from typing import Any

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

from _common import write_results  # noqa: E402


def _rows(payload: dict[str, Any]) -> list[tuple[str, float, float, float]]:
    """(row key, single seconds, single / flat, load) of every row of one run."""
    out = []
    rows = payload["rows"]
    if rows and "data" in rows[0]:  # --real-only
        for r in rows:
            out.append((f"{r['data']}: {r['method'].split(' (')[0]}", r["single_s"]["median"], r["single_vs_flat"],
                        r["load"][0]))
        return out
    flat = {r["n_places"]: r["single_s"]["median"] for r in rows if r["method"] == "faiss.IndexFlatIP"}
    for r in rows:
        method = r["method"].split(" (auto")[0]
        out.append((f"N = {r['n_places']:,d}: {method}", r["single_s"]["median"],
                    r["single_s"]["median"] / flat[r["n_places"]], payload["load_before"][0]))
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--label", action="append", nargs="+", required=True, metavar=("LABEL", "FILE"),
                        help="a version's label and its results files")
    args = parser.parse_args()
    summary: dict[str, dict[str, Any]] = {}
    for label, *files in args.label:
        per_row: dict[str, list[tuple[float, float, float]]] = defaultdict(list)
        for f in files:
            for key, seconds, ratio, load in _rows(json.loads(Path(f).read_text())):
                per_row[key].append((seconds, ratio, load))
        summary[label] = {key: {"runs": len(v), "single_us_median": float(np.median([s for s, _, _ in v])) * 1e6,
                                "single_vs_flat_median": float(np.median([r for _, r, _ in v])),
                                "single_vs_flat_runs": [round(r, 3) for _, r, _ in v],
                                "loads": [round(x, 2) for _, _, x in v]} for key, v in per_row.items()}
    labels = list(summary)
    for key in summary[labels[0]]:
        cells = [f"{summary[lab][key]['single_us_median']:9.1f} µs {summary[lab][key]['single_vs_flat_median']:6.3f}× "
                 f"(load {'/'.join(f'{x:.1f}' for x in summary[lab][key]['loads'])})"
                 for lab in labels if key in summary[lab]]
        print(f"{key:<62} " + "  |  ".join(cells))
    print(f"wrote {write_results('bench_codes_single_query', {'versions': summary, 'inputs': args.label})}")


if __name__ == "__main__":
    main()
