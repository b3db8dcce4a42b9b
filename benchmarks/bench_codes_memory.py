"""Inference memory and cold start of btel-codes: resident memory after ``load`` and queries, against N·K/8 + 32 MB.

A btel-codes model (d = 256, 64 KB, periodic codes: the setting of ``benchmarks/bench_codes.py``)
(``--code``: another family) is fitted on a synthetic route of ``--places`` places and saved in a temporary folder, in a child
process. Then, each in a fresh process (so that every peak is that process' own):

- **baseline** — imports numpy, faiss and btel's code localizer and loads the query file, but no
  model: the peer whose resident memory is subtracted;
- **one process per decode** (``--decodes``; default 'auto' and 'exact') — the same
  imports and queries, then ``btel.load``, the first single query (timed), 100 single queries and
  one batch of ``--batch`` queries.

The fit itself runs in a fresh process on the map loaded from a file (``normalize='none'``, the
rows normalised beforehand as in ``bench_codes.py``; then the default ``'l2'`` front end): its peak
resident memory (``ru_maxrss``) minus the resident memory before the fit is the fit's own peak above
the map.

Resident memory is read from ``/proc/self/statm`` (current) and ``getrusage(RUSAGE_SELF).ru_maxrss``
(peak) after each step. Inference memory = resident memory after the queries − the baseline's,
reported against N·K/8 + 32 MB (N·K/8: the packed codebook), beside the peaks after the first
query, the 100 single queries and the batch (− the baseline's peak). Writes
``benchmarks/results/bench_codes_memory.json`` and prints a table with the load average::

    python benchmarks/bench_codes_memory.py            # N = 10⁶ (the fit takes ≈ 0.5–1 min)
    python benchmarks/bench_codes_memory.py --quick    # N = 10⁵
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

HERE = Path(__file__).resolve().parent
MB = 1 << 20

_BUILD = """
import sys
sys.path.insert(0, sys.argv[1])
import numpy as np
from bench_codes import route
n, n_queries, folder = int(sys.argv[2]), int(sys.argv[3]), sys.argv[4]
X, Q, truth = route(n, n_queries)
np.save(folder + "/map.npy", X)
np.save(folder + "/queries.npy", Q)
print(X.nbytes)
"""

# The fit in a fresh process whose map is already in memory: its peak above that is the fit's own.
_FIT = """
import json, os, resource, sys, time
import numpy as np
from btel.methods.codes.estimator import CodeLocalizer
folder, code, normalize, save = sys.argv[1], sys.argv[2], sys.argv[3], sys.argv[4] == "save"
PAGE = os.sysconf("SC_PAGE_SIZE")
X = np.load(folder + "/map.npy")
with open("/proc/self/statm") as f:
    rss_before = int(f.read().split()[1]) * PAGE
peak_before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
start = time.perf_counter()
params = {} if code == "default" else {"code": code}
model = CodeLocalizer(budget="64KB", normalize=normalize, decode="exact", **params).fit(X)
fit_s = time.perf_counter() - start
peak_after = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
if save:
    model.save(folder + "/model.btel")
print(json.dumps({"normalize": normalize, "fit_s": fit_s, "map_bytes": int(X.nbytes), "rss_before_fit": rss_before,
                  "peak_before_fit": peak_before, "peak_after_fit": peak_after,
                  "fit_peak_above_map_bytes": peak_after - rss_before}))
"""

_MEASURE = """
import json, os, resource, sys, time
import numpy as np, faiss, btel
import btel.methods.codes.estimator

PAGE = os.sysconf("SC_PAGE_SIZE")

def rss():
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * PAGE

def peak():
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024

folder, decode, batch = sys.argv[1], sys.argv[2], int(sys.argv[3])
Q = np.load(folder + "/queries.npy")
out = {"decode": decode, "rss_start": rss(), "peak_start": peak()}
if decode != "baseline":
    start = time.perf_counter()
    model = btel.load(folder + "/model.btel")
    out["load_s"] = time.perf_counter() - start
    model.set_params(decode=decode)
    out.update(rss_load=rss(), peak_load=peak(), n_places=int(model.n_places_), n_codes=int(model.n_codes_),
               nbytes=int(model.nbytes), configuration=model.summary())
    start = time.perf_counter()
    model.predict(Q[:1])
    out["first_query_s"] = time.perf_counter() - start
    out.update(rss_first=rss(), peak_first=peak())
    start = time.perf_counter()
    for j in range(1, 101):
        model.predict(Q[j % len(Q) : j % len(Q) + 1])
    out["single_s"] = (time.perf_counter() - start) / 100
    out.update(rss_single=rss(), peak_single=peak())
    start = time.perf_counter()
    model.predict(Q[:batch])
    out["batch_s"] = time.perf_counter() - start
    out.update(rss_batch=rss(), peak_batch=peak())
print(json.dumps(out))
"""


def child(code: str, *args: str) -> str:
    """Run ``code`` in a fresh Python process; its stdout's last line."""
    proc = subprocess.run([sys.executable, "-c", code, *args], check=False, capture_output=True, text=True)
    if proc.returncode != 0:
        raise RuntimeError(f"child failed: {proc.stderr[-3000:]}")
    return proc.stdout.strip().splitlines()[-1]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--places", type=int, default=None, help="N (default 10⁶; --quick: 10⁵)")
    parser.add_argument("--quick", action="store_true", help="N = 10⁵")
    parser.add_argument("--batch", type=int, default=1000, help="queries in the batch call")
    parser.add_argument("--decodes", nargs="+", default=["auto", "exact"],
                        help="decodes measured, one process each (set on the loaded model)")
    parser.add_argument("--code", default="default", help="code family of the fit ('default': CodeLocalizer's, "
                        "as in bench_codes.py; 'random': decoded by faiss' packed scan)")
    parser.add_argument("--out", default="bench_codes_memory", help="results file name in benchmarks/results")
    args = parser.parse_args(argv)
    n = args.places or (100_000 if args.quick else 1_000_000)
    sys.path.insert(0, str(HERE))
    from _common import write_results

    load_before = os.getloadavg()
    rows: list[dict[str, Any]] = []
    with tempfile.TemporaryDirectory() as folder:
        print(f"N = {n:,d}: fitting and saving the model …", flush=True)
        child(_BUILD, str(HERE), str(n), str(args.batch), folder)
        fits = []
        for normalize in ("none", "l2"):  # the script's fit (rows normalised beforehand), then the default front end
            fits.append(json.loads(child(_FIT, folder, args.code, normalize, "save" if normalize == "none" else "")))
            f = fits[-1]
            print(f"  fit (normalize={normalize}) {f['fit_s']:.1f} s: peak {f['peak_after_fit'] / MB:.0f} MB, "
                  f"{f['fit_peak_above_map_bytes'] / MB:.0f} MB above the {f['map_bytes'] / MB:.0f} MB map "
                  f"(process before the fit {f['rss_before_fit'] / MB:.0f} MB)", flush=True)
        fit_s = fits[0]["fit_s"]
        file_bytes = Path(folder, "model.btel").stat().st_size
        base = json.loads(child(_MEASURE, folder, "baseline", str(args.batch)))
        for decode in args.decodes:
            row = json.loads(child(_MEASURE, folder, decode, str(args.batch)))
            row["load_average"] = list(os.getloadavg())
            row["packed_bytes"] = row["n_places"] * -(-row["n_codes"] // 8)
            row["bound_bytes"] = row["packed_bytes"] + 32 * MB
            row["inference_bytes"] = row["rss_batch"] - base["rss_start"]
            row["inference_peak_bytes"] = row["peak_batch"] - base["peak_start"]
            row["within_bound"] = row["inference_bytes"] <= row["bound_bytes"]
            rows.append(row)
    payload = {"n_places": n, "code": args.code, "fit_s": fit_s, "fits": fits, "model_file_bytes": file_bytes, "baseline": base, "rows": rows,
               "load_before": list(load_before), "load_after": list(os.getloadavg())}
    path = write_results(args.out, payload)

    print(f"baseline (imports + queries, no model): RSS {base['rss_start'] / MB:.1f} MB, peak {base['peak_start'] / MB:.1f} MB")
    print(f"{'decode':<8} {'load s':>7} {'first s':>8} {'1 query ms':>10} {'batch s':>8} | RSS − baseline MB: "
          f"{'load':>7} {'first':>7} {'100':>7} {'batch':>7} | peak − baseline MB: {'first':>6} {'100':>6} "
          f"{'batch':>6} | {'N·K/8+32':>8} ok   load avg")
    for r in rows:
        d = {k: (r[k] - base["rss_start"]) / MB for k in ("rss_load", "rss_first", "rss_single", "rss_batch")}
        p = {k: (r[k] - base["peak_start"]) / MB for k in ("peak_first", "peak_single")}
        print(f"{r['decode']:<8} {r['load_s']:7.3f} {r['first_query_s']:8.3f} {r['single_s'] * 1e3:10.3f} "
              f"{r['batch_s']:8.3f} | {'':>17} {d['rss_load']:7.1f} {d['rss_first']:7.1f} {d['rss_single']:7.1f} "
              f"{d['rss_batch']:7.1f} | {'':>18} {p['peak_first']:6.1f} {p['peak_single']:6.1f} "
              f"{r['inference_peak_bytes'] / MB:6.1f} | {r['bound_bytes'] / MB:8.1f} "
              f"{'yes' if r['within_bound'] else 'NO ':<4} {r['load_average'][0]:.2f}")
    print(f"N = {n:,d}, K = {rows[0]['n_codes'] if rows else '?'}, {rows[0]['configuration'] if rows else ''}; fit {fit_s:.1f} s; load average "
          f"{load_before[0]:.2f} before, {payload['load_after'][0]:.2f} after; wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
