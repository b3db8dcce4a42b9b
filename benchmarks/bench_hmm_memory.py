"""Peak memory of batch HMM decoding: `btel localize --hmm` (blocked) against the whole score matrix.

Issue #13 item 9: `btel localize --hmm` on 200k queries with N = 2000 peaked at 10 GB because it
held the full (queries × N) score matrix. ``predict_sequence(Q, 'hmm')`` now scores blocks of
about 2²² values and updates the decoder row by row (O(block × N) memory). This script runs, each
in its own process so that peak resident memory is measured per run:

- ``cli``  — ``btel localize MODEL Q.npy -o p.csv --hmm`` (the blocked path);
- ``full`` — the peer: ``decode_sequence(emission_scores(model, Q))`` on the whole matrix at once
  (what the command did before).

and checks both give the same places. Writes ``benchmarks/results/bench_hmm_memory.json``::

    python benchmarks/bench_hmm_memory.py --queries 50000 --places 2000
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent

_FULL = """
import sys, numpy as np, btel
from btel.sequence.hmm import decode_sequence, emission_scores
model = btel.load(sys.argv[1]); Q = np.load(sys.argv[2])
np.save(sys.argv[3], decode_sequence(emission_scores(model, Q)))
"""


def run(args: list[str]) -> tuple[float, float]:
    """(seconds, peak resident MB) of one child process."""
    start = time.perf_counter()
    proc = subprocess.Popen(args, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    _, status, usage = os.wait4(proc.pid, 0)
    seconds = time.perf_counter() - start
    if os.waitstatus_to_exitcode(status) != 0:
        raise RuntimeError(f"{args[:3]} failed: {proc.stderr.read()[-2000:]}")
    return seconds, usage.ru_maxrss / 1024


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--queries", type=int, default=50_000)
    parser.add_argument("--places", type=int, default=2000)
    parser.add_argument("--dim", type=int, default=64)
    args = parser.parse_args(argv)
    sys.path.insert(0, str(HERE))
    from _common import write_results

    from btel import BTELocalizer
    from btel.datasets import synthetic_route

    route = synthetic_route(args.places, args.dim, seed=0)
    reps = -(-args.queries // args.places)
    Q = np.concatenate([route.queries] * reps)[: args.queries]
    with tempfile.TemporaryDirectory(prefix="btel-hmm-") as tmp:
        folder = Path(tmp)
        model_path = BTELocalizer(progress=False).fit(route.map).save(folder / "m.npz")
        np.save(folder / "q.npy", Q)
        load_before = os.getloadavg()
        cli_s, cli_mb = run([sys.executable, "-m", "btel.cli", "localize", str(model_path), str(folder / "q.npy"),
                             "-o", str(folder / "p.csv"), "--hmm"])
        full_s, full_mb = run([sys.executable, "-c", _FULL, str(model_path), str(folder / "q.npy"),
                               str(folder / "full.npy")])
        cli_places = np.loadtxt(folder / "p.csv", delimiter=",", skiprows=1, dtype=np.int64)[:, 1]
        same = bool(np.array_equal(cli_places, np.load(folder / "full.npy")))
    score_matrix_mb = args.queries * args.places * 8 / 1e6
    result = {
        "queries": args.queries, "places": args.places, "dim": args.dim,
        "score_matrix_mb": round(score_matrix_mb, 1),
        "cli_blocked": {"seconds": round(cli_s, 2), "peak_rss_mb": round(cli_mb, 1)},
        "full_matrix_peer": {"seconds": round(full_s, 2), "peak_rss_mb": round(full_mb, 1)},
        "same_places": same,
        "load_average_before": [round(x, 2) for x in load_before],
        "command": f"python benchmarks/bench_hmm_memory.py --queries {args.queries} --places {args.places}",
    }
    print(json.dumps(result, indent=2))
    print(f"written to {write_results('bench_hmm_memory', result)}")
    return 0 if same else 1


if __name__ == "__main__":
    sys.exit(main())
