"""Parsers for ``numpy.savetxt`` lines (``'%.18e'``) in blocks, against the stream's own parse, same run.

Issue 35 asks ``btel localize --stream`` for ≥ 20,000 savetxt lines/s at d = 500; the parse is the
ceiling (``docs/decisions/streaming.md``). This study times, on the same blocks of ``--block`` lines
(float32 descriptors, both savetxt delimiters), interleaved and best of ``--repeats``:

- ``parse_lines``: :func:`btel.sequence.lineparse.parse_lines` (orjson per line, one array per block);
- ``orjson only``: orjson's parse of the same lines, no array built (the floor of that path);
- ``orjson + np.array`` / ``orjson + np.fromiter``: the same, then one float64 array built from the
  nested lists by ``np.array`` (``parse_lines`` before 2026-11-28) or by ``np.fromiter`` over the
  chained floats (``parse_lines`` now): what the conversion costs;
- ``fixed numpy``: a vectorised parser of savetxt's fixed format written for this study
  (:func:`parse_fixed`: the ``e`` of every token found in one pass, 32-byte windows gathered, digits
  turned into integers four at a time in uint32 words, the value in float64 from the 19-digit
  mantissa and a power of ten, the block refused where any value lies within 8 float64 ulps of a
  float32 rounding midpoint), on the whole block and on sub-blocks of 32 lines (cache-sized);
- ``float per token``: Python's ``float`` on every token (the parser before issue 22);
- ``orjson, one document per block``: the block's lines joined into one JSON document, one orjson
  call, then ``np.fromiter``: the floor of a stream with no per-line Python step at all;
- ``numpy.fromstring`` and ``numpy.loadtxt``: numpy's own C text parsers on the whole block;
- compiled CSV readers, each when it is importable (none is a btel dependency; install them beside
  btel to include them): ``polars.read_csv``, ``pyarrow.csv.read_csv`` and ``pandas.read_csv``
  (C engine), the block handed over as one bytes buffer with every column typed float64, the
  result turned into one float32 array (what the stream would need); and pysimdjson (simdjson's
  DOM parser), the block as one JSON document whose doubles come out as one buffer (``as_buffer``).

Every parser's float32 rows are checked bit for bit against ``float(token)`` → float32 on every
block first. Ratios are to ``parse_lines`` in the same run (the machine is shared: absolute figures
move with its load, printed).

    python benchmarks/studies/stream_parsers.py            # ≈ 1 min
    python benchmarks/studies/stream_parsers.py --block 256 --repeats 30
    pip install --target /tmp/csv polars pyarrow pandas pysimdjson   # then, to time the compiled readers too:
    PYTHONPATH=/tmp/csv python benchmarks/studies/stream_parsers.py

Writes ``benchmarks/results/stream_parsers.json``.
"""

from __future__ import annotations

import argparse
import io
import itertools
import os
import sys
import time
from typing import Callable

import numpy as np
import orjson

from _common import write_results

_U4 = np.uint32
_POW10 = np.array([float(f"1e{k}") for k in range(-117, 82)])  # 10**(x - 18) at x + 99, |x| <= 99
_F32_MAX = float(np.finfo(np.float32).max)


def parse_fixed(lines: list[bytes], d: int) -> np.ndarray | None:
    """Float32 rows of savetxt ``'%.18e'`` lines (single-byte separators), or None where the block is
    not exactly that format or a value needs the exact parser (module docstring)."""
    n_lines = len(lines)
    buf = b"".join([b"\n" * 4, *lines, b"\0" * 8])
    a = np.frombuffer(buf, np.uint8)
    e = np.flatnonzero(a == ord("e"))
    if len(e) != n_lines * d or not all(line.endswith(b"\n") for line in lines):
        return None
    windows = np.lib.stride_tricks.as_strided(a, (len(a) - 31, 32), (1, 1))
    # Bytes 4..27: the token 'D.dddddddddddddddddde+XX'; byte 3: its sign; byte 28: the separator.
    t = windows[e - 24]
    w = t.view(_U4)
    neg = t[:, 3] == ord("-")
    sep = t[:, 28].reshape(n_lines, d)
    mid = sep[:, :-1]
    w1, w6 = w[:, 1], w[:, 6]
    exp_sign = w6 & _U4(0xFFFF)
    exp_neg = exp_sign == _U4(0x2D65)
    if not (e[0] - 20 - neg[0] == 4 and (np.diff(e) - neg[1:] == 25).all() and (sep[:, -1] == 10).all()
            and ((mid == 32) | (mid == 44) | (mid == 9)).all() and ((w1 & _U4(0xFF00)) == _U4(0x2E00)).all()
            and (exp_neg | (exp_sign == _U4(0x2B65))).all()):
        return None
    w[:, 1] = ((w1 & _U4(0xFF)) << _U4(8)) | (w1 & _U4(0xFFFF0000)) | _U4(0x30)  # '0', D, d1, d2
    w[:, 6] = (w6 & _U4(0xFFFF0000)) | _U4(0x3030)  # '0', '0', X, X
    g = w[:, 1:7]
    if (((g + _U4(0x46464646)) | (g - _U4(0x30303030))) & _U4(0x80808080)).any():  # a byte not a digit
        return None
    v = g - _U4(0x30303030)
    v = (v * _U4(10) + (v >> _U4(8))) & _U4(0x00FF00FF)
    v = (v * _U4(100) + (v >> _U4(16))) & _U4(0xFFFF)  # each word: its four digits' value
    f = v.astype(np.float64)
    mantissa = (((f[:, 0] * 1e4 + f[:, 1]) * 1e4 + f[:, 2]) * 1e4 + f[:, 3]) * 1e4 + f[:, 4]
    exponent = v[:, 5].astype(np.intp)
    exponent[exp_neg] *= -1
    x = mantissa * _POW10[exponent + 99]
    np.negative(x, out=x, where=neg)
    near = ((x.view(np.uint64) + np.uint64((8 - (1 << 28)) % (1 << 64))) & np.uint64((1 << 29) - 1)) <= 16
    ax = np.abs(x)
    if near.any() or ax.max() > _F32_MAX * (1 - 1e-9) or ((ax < 2.0 ** -126) & (ax != 0)).any():
        return None
    return x.reshape(n_lines, d).astype(np.float32)


def orjson_only(lines: list[bytes]) -> list[list[float]]:
    loads = orjson.loads
    return [loads(b"[" + (line if b"," in line else line.replace(b" ", b",")) + b"]") for line in lines]


def orjson_nested_array(lines: list[bytes]) -> np.ndarray:
    """orjson per line, then one float64 array from the nested lists (``parse_lines`` before 2026-11-28)."""
    return np.array(orjson_only(lines), dtype=np.float64)


def orjson_flat_fromiter(lines: list[bytes], d: int) -> np.ndarray:
    """orjson per line, then one float64 array by ``np.fromiter`` over the chained floats (``parse_lines``)."""
    parsed = orjson_only(lines)
    return np.fromiter(itertools.chain.from_iterable(parsed), dtype=np.float64,
                       count=len(parsed) * d).reshape(len(parsed), d)


def orjson_one_document(lines: list[bytes], d: int) -> np.ndarray:
    """The whole block as one JSON document (no Python loop over its lines), then ``np.fromiter``: what
    a stream that skipped every per-line step would still pay."""
    block = b"".join(lines).rstrip(b"\n")
    if b"," not in block:
        block = block.replace(b" ", b",")
    parsed = orjson.loads(b"[[" + block.replace(b"\n", b"],[") + b"]]")
    return np.fromiter(itertools.chain.from_iterable(parsed), dtype=np.float64,
                       count=len(parsed) * d).reshape(len(parsed), d)


def numpy_fromstring(block: bytes, delimiter: str, d: int) -> np.ndarray:
    """``np.fromstring`` (numpy's C text parser) on the whole block, newlines read as separators."""
    if delimiter == ",":
        block = block.rstrip(b"\n").replace(b"\n", b",")
    return np.fromstring(block, dtype=np.float64, sep=delimiter).reshape(-1, d).astype(np.float32)


def float_per_token(lines: list[bytes]) -> np.ndarray:
    values = [[float(t) for t in line.replace(b",", b" ").split()] for line in lines]
    return np.array(values).astype(np.float32)


def compiled_readers(d: int, delimiter: str) -> dict[str, Callable[[bytes], np.ndarray]]:
    """The importable compiled CSV readers: name → function of a block's bytes → float32 rows."""
    readers: dict[str, Callable[[bytes], np.ndarray]] = {}
    try:
        import polars as pl

        schema = {f"column_{i + 1}": pl.Float64 for i in range(d)}
        readers[f"polars {pl.__version__}"] = lambda block: pl.read_csv(
            block, separator=delimiter, has_header=False, schema=schema).to_numpy().astype(np.float32)
    except ImportError:
        pass
    try:
        import pyarrow as pa
        import pyarrow.csv as pcsv

        read = pcsv.ReadOptions(autogenerate_column_names=True)
        parse = pcsv.ParseOptions(delimiter=delimiter)
        convert = pcsv.ConvertOptions(column_types={f"f{i}": pa.float64() for i in range(d)})
        readers[f"pyarrow {pa.__version__}"] = lambda block: np.column_stack([
            column.to_numpy() for column in pcsv.read_csv(pa.BufferReader(block), read_options=read,
                                                          parse_options=parse,
                                                          convert_options=convert).columns]).astype(np.float32)
    except ImportError:
        pass
    try:
        import simdjson

        json_parser = simdjson.Parser()
        comma = delimiter == ","

        def read_simdjson(block: bytes) -> np.ndarray:
            # One JSON document per block; as_buffer hands the doubles over without Python floats.
            lines = block.rstrip(b"\n").split(b"\n")
            text = b"[[" + b"],[".join(lines if comma else [line.replace(b" ", b",") for line in lines]) + b"]]"
            values = np.frombuffer(json_parser.parse(text).as_buffer(of_type="d"), dtype=np.float64)
            return values.reshape(len(lines), d).astype(np.float32)

        readers[f"pysimdjson {getattr(simdjson, '__version__', '')}".rstrip()] = read_simdjson
    except ImportError:
        pass
    try:
        import pandas as pd

        readers[f"pandas {pd.__version__} (C engine)"] = lambda block: pd.read_csv(
            io.BytesIO(block), sep=delimiter, header=None, dtype=np.float64,
            engine="c").to_numpy().astype(np.float32)
    except ImportError:
        pass
    return readers


def main() -> None:
    from btel.sequence.lineparse import parse_lines

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--d", type=int, default=500)
    parser.add_argument("--block", type=int, default=256)
    parser.add_argument("--repeats", type=int, default=20)
    args = parser.parse_args()
    rng = np.random.default_rng(0)
    rows = []
    for delimiter, name in ((" ", "savetxt"), (",", "savetxt-comma")):
        q = rng.standard_normal((args.block, args.d)).astype(np.float32)
        q /= np.linalg.norm(q, axis=1, keepdims=True)
        out = io.BytesIO()
        np.savetxt(out, q, delimiter=delimiter)
        lines = out.getvalue().splitlines(keepends=True)
        truth = float_per_token(lines)
        sub = 32
        candidates: dict[str, Callable[[], object]] = {
            "parse_lines": lambda: parse_lines(lines, args.d),
            "orjson only": lambda: orjson_only(lines),
            "orjson + np.array of the nested lists": lambda: orjson_nested_array(lines),
            "orjson + np.fromiter, flat": lambda: orjson_flat_fromiter(lines, args.d),
            "fixed numpy (block)": lambda: parse_fixed(lines, args.d),
            f"fixed numpy ({sub}-line sub-blocks)":
                lambda: [parse_fixed(lines[i:i + sub], args.d) for i in range(0, len(lines), sub)],
            "float per token": lambda: float_per_token(lines),
            "orjson, one document per block": lambda: orjson_one_document(lines, args.d),
        }
        block = b"".join(lines)
        # numpy's own C parsers (correctly rounded decimal conversion), checked like the compiled readers below.
        numpy_readers = {
            "numpy.fromstring (block)": lambda: numpy_fromstring(block, delimiter, args.d),
            "numpy.loadtxt (block)": lambda: np.loadtxt(io.BytesIO(block), delimiter=None if delimiter == " "
                                                        else delimiter, dtype=np.float64).astype(np.float32),
        }
        for key, read in numpy_readers.items():
            if not np.array_equal(read().view(np.uint32), truth.view(np.uint32)):
                raise SystemExit(f"{key} disagrees with float() on these lines")
            candidates[key] = read
        if not np.array_equal(orjson_one_document(lines, args.d).astype(np.float32).view(np.uint32),
                              truth.view(np.uint32)):
            raise SystemExit("orjson on one document disagrees with float() on these lines")
        for key, read in compiled_readers(args.d, delimiter).items():
            if not np.array_equal(read(block).view(np.uint32), truth.view(np.uint32)):
                raise SystemExit(f"{key} disagrees with float() on these lines")
            candidates[key] = lambda read=read: read(block)
        fixed = parse_fixed(lines, args.d)
        if fixed is None or not np.array_equal(fixed.view(np.uint32), truth.view(np.uint32)):
            raise SystemExit("the fixed-format parser disagrees with float() on these lines")
        if not np.array_equal(parse_lines(lines, args.d)[0].view(np.uint32), truth.view(np.uint32)):
            raise SystemExit("parse_lines disagrees with float() on these lines")
        load = os.getloadavg()
        best = {key: np.inf for key in candidates}
        for _ in range(args.repeats):
            for key, fn in candidates.items():
                start = time.perf_counter()
                fn()
                best[key] = min(best[key], time.perf_counter() - start)
        load_after = os.getloadavg()
        for key, seconds in best.items():
            row = {"format": name, "parser": key, "d": args.d, "block": args.block,
                   "lines_per_s": args.block / seconds, "us_per_line": seconds / args.block * 1e6,
                   "ratio_vs_parse_lines": best["parse_lines"] / seconds, "load": [load[0], load_after[0]]}
            rows.append(row)
            print(f"{name:<14} {key:<34} {row['lines_per_s']:>9,.0f} lines/s  "
                  f"{row['us_per_line']:6.1f} µs/line  {row['ratio_vs_parse_lines']:5.2f}× parse_lines  "
                  f"(load {load[0]:.1f} → {load_after[0]:.1f})", flush=True)
    path = write_results("stream_parsers", {"rows": rows, "command": " ".join(["python", *sys.argv])})
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
