"""LSH's asymmetric scan of packed codes: lookup tables, unpacked row blocks, and the float32 copy before.

For each (N rows, P bits) shape and batch size, random codes are scanned for the best row of each
query by (both scans timed from the raw queries, their rounding to the exact grid of
:func:`btel.methods.baselines.signscan.query_rows` included):

- **tables**: faiss ``ProductQuantizer.search_ip`` with the byte's 256 ±1 patterns as codebook (what
  ``lsh`` does below :data:`btel.methods.baselines.signscan.TABLE_QUERIES` queries);
- **blocks**: rows unpacked to ±1 a block at a time (``BLOCK_VALUES`` values) and one matrix product
  each, merged block by block (what ``lsh`` does from that many queries on);
- **float copy**: the product with a float32 ±1 copy of all codes held in memory (``lsh`` before; N·P·4
  bytes), with ``argmax``; the reference speed, not an option any more.

Best of 5 rounds, one thread (BLAS and faiss), milliseconds per batch. The load average is recorded.

    python benchmarks/studies/lsh_projection_scan.py

Writes ``benchmarks/results/bench_lsh_scan.json``.
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np
from _common import write_results

from btel.methods.baselines import signscan
from btel.core.threads import limit_threads

SHAPES = ((10_000, 64), (10_000, 256), (10_000, 1024), (100_000, 80), (500, 8192))
BATCHES = (1, 4, 8, 16, 64, 500)


def best_ms(fn, rounds: int = 5) -> float:
    fn()
    times = []
    for _ in range(rounds):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return min(times) * 1e3


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(
        description=__doc__.splitlines()[0],
        epilog="Writes benchmarks/results/bench_lsh_scan.json.")
    parser.parse_args(argv)
    rng = np.random.default_rng(0)
    rows, load = [], os.getloadavg()
    start = time.time()
    with limit_threads(1):
        for n_rows, n_bits in SHAPES:
            codes = rng.integers(0, 256, (n_rows, n_bits // 8), dtype=np.uint8)
            tables = signscan.byte_tables(codes.shape[1])
            copy = np.take(signscan.BYTE_SIGNS, codes, axis=0).reshape(n_rows, -1)

            def grid(P, n_bytes=codes.shape[1]):  # the queries as lsh hands them to a scan
                return signscan.query_rows(P, n_bytes)
            for n_queries in BATCHES:
                P = rng.standard_normal((n_queries, n_bits), dtype=np.float32)
                row = {"n_rows": n_rows, "n_bits": n_bits, "n_queries": n_queries,
                       "tables_ms": best_ms(lambda: signscan.scan_tables(tables, codes, grid(P), 1)),
                       "blocks_ms": best_ms(lambda: signscan.scan_blocks(codes, grid(P), 1)),
                       "float_copy_ms": best_ms(lambda: np.argmax(P @ copy.T, axis=1))}
                rows.append(row)
                print(f"N {n_rows:>7}  P {n_bits:>5}  queries {n_queries:>4}:  "
                      f"tables {row['tables_ms']:8.2f}  blocks {row['blocks_ms']:8.2f}  "
                      f"float copy {row['float_copy_ms']:8.2f} ms ({copy.nbytes / 1e6:.0f} MB)", flush=True)
    out = write_results("bench_lsh_scan", {"rows": rows, "load": load, "load_end": os.getloadavg(),
                                           "seconds": time.time() - start})
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
