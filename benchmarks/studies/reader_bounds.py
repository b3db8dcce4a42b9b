"""The evidence behind two of the readers' bounds (docs/decisions/reader-bounds.md).

1. **Image decoding memory** (:func:`btel.descriptors.images.decode_bytes`): the peak resident
   memory OpenCV's ``imdecode`` (and, for colour, the BGR→RGB copy) adds per pixel, for every
   format and mode btel decodes, each measured in a fresh process, against the bound.
2. **Radius-search work** (:data:`btel.datasets.positions.DISTANCES_PER_PAIR`): distances a
   KD-tree computes per query and per pair on position sets shaped like VPR data (street grids,
   routes) and on the adversarial ring, against the bound.

    python benchmarks/studies/reader_bounds.py            # ≈ 2 min on 2 shared cores
    python benchmarks/studies/reader_bounds.py --quick    # smaller images and position sets

Writes ``benchmarks/results/bench_reader_bounds.json`` and prints both tables as markdown.
"""

from __future__ import annotations

import argparse
import io
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

HERE = Path(__file__).resolve().parent  # benchmarks/studies: its _common re-exports the helpers
sys.path.insert(0, str(HERE))

from _common import write_results  # noqa: E402

#: Measured in a child (Linux): the peak resident memory during one decode (VmHWM, reset just before)
#: over the resident memory before it, per pixel.
_DECODE = r"""
import sys, numpy as np, cv2

def status(key):
    with open("/proc/self/status") as fh:
        return next(int(line.split()[1]) for line in fh if line.startswith(key))  # KiB

data = np.fromfile(sys.argv[1], dtype=np.uint8)
grey = sys.argv[2] == "grey"
with open("/proc/self/clear_refs", "w") as fh:
    fh.write("5")  # reset the peak (VmHWM) to the resident memory now
before = status("VmRSS:")
image = cv2.imdecode(data, cv2.IMREAD_GRAYSCALE if grey else cv2.IMREAD_COLOR)
if not grey:
    image = cv2.cvtColor(image, cv2.COLOR_BGR2RGB)
print((status("VmHWM:") - before) * 1024 / (image.shape[0] * image.shape[1]))
"""


def _images(width: int, height: int) -> dict[str, bytes]:
    """name → encoded file: every decoded format, and TIFFs in one strip (OpenCV's largest buffers)."""
    import cv2
    from PIL import Image

    base = (np.add.outer(np.arange(height), np.arange(width)) % 251).astype(np.uint8)
    rgb = np.stack([base, base[::-1], base[:, ::-1]], -1)

    def encode(image: np.ndarray, fmt: str, **options: Any) -> bytes:
        buffer = io.BytesIO()
        Image.fromarray(image).save(buffer, format=fmt, **options)
        return buffer.getvalue()

    def one_strip(image: np.ndarray) -> bytes:
        options = [cv2.IMWRITE_TIFF_COMPRESSION, 1, cv2.IMWRITE_TIFF_ROWSPERSTRIP, height]
        ok, data = cv2.imencode(".tif", image, options)
        return data.tobytes()

    bgr, rgba = rgb[..., ::-1], np.dstack([rgb, base])
    return {"PNG grey": encode(base, "PNG"), "PNG RGB": encode(rgb, "PNG"), "PNG RGBA": encode(rgba, "PNG"),
            "PNG 16-bit grey": encode(base.astype(np.uint16) * 257, "PNG"),
            "PNG palette": encode(np.asarray(Image.fromarray(base).convert("P")), "PNG"),
            "JPEG RGB": encode(rgb, "JPEG"), "JPEG RGB progressive": encode(rgb, "JPEG", progressive=True),
            "JPEG grey": encode(base, "JPEG"), "BMP RGB": encode(rgb, "BMP"), "TIFF RGB": encode(rgb, "TIFF"),
            "TIFF RGB deflate": encode(rgb, "TIFF", compression="tiff_deflate"),
            "TIFF grey, one strip": one_strip(base),
            "TIFF 16-bit grey, one strip": one_strip(base.astype(np.uint16) * 257),
            "TIFF RGBA, one strip": one_strip(np.dstack([bgr, base])),
            "TIFF 16-bit RGB, one strip": one_strip(bgr.astype(np.uint16) * 257),
            "TIFF 16-bit RGBA, one strip": one_strip(np.dstack([bgr, base]).astype(np.uint16) * 257),
            "PPM RGB": encode(rgb, "PPM"), "WebP RGB": encode(rgb, "WEBP"),
            "WebP RGB lossless": encode(rgb, "WEBP", lossless=True)}


def decode_memory(width: int, height: int) -> list[dict[str, Any]]:
    from btel.descriptors.images import decode_bytes, image_header

    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for name, data in _images(width, height).items():
            path = Path(tmp) / "image"
            path.write_bytes(data)
            header = image_header(data)
            row: dict[str, Any] = {"format": name, "channels": header["channels"],
                                   "sample_bytes": header["sample_bytes"]}
            for mode in ("grey", "colour"):
                out = subprocess.run([sys.executable, "-c", _DECODE, str(path), mode], capture_output=True,
                                     text=True, check=True)
                bound = decode_bytes(width, height, header["channels"], grey=mode == "grey",
                                     sample_bytes=header["sample_bytes"], tiff=header["format"] == "TIFF")
                row[f"{mode}_measured_b_per_px"] = round(float(out.stdout), 2)
                row[f"{mode}_bound_b_per_px"] = bound / (width * height)
            rows.append(row)
    return rows


def _position_sets(scale: float) -> dict[str, tuple[np.ndarray, np.ndarray, float]]:
    rng = np.random.default_rng(0)
    n = int(250_000 * scale)
    street = rng.uniform(0, 5000, (n, 2))
    street_q = street[rng.integers(0, n, n // 12)] + rng.normal(0, 5, (n // 12, 2))
    route = np.cumsum(rng.normal(0, 1, (n // 5, 2)) + [2.0, 0.0], axis=0)
    route_q = route + rng.normal(0, 3, route.shape)
    same = np.repeat(rng.uniform(0, 5000, (n // 100, 2)), 20, axis=0)  # 20 images per spot (panoramas)
    angle = np.linspace(0, 2 * np.pi, int(50_000 * scale), endpoint=False)
    ring = 100 * np.stack([np.cos(angle), np.sin(angle)], 1)
    return {"street grid, 25 m": (street, street_q, 25.0), "street grid, 100 m": (street, street_q, 100.0),
            "route, 25 m": (route, route_q, 25.0), "20 images per spot, 25 m": (same, same[::7], 25.0),
            "ring, queries at its centre, r − 1e-9": (ring, np.zeros((1000, 2)), 100 * (1 - 1e-9))}


def search_work(scale: float) -> list[dict[str, Any]]:
    from sklearn.neighbors import KDTree

    from btel.datasets.positions import DISTANCES_PER_PAIR
    from btel.core.limits import DEFAULT_MEMORY_LIMIT

    bound = DISTANCES_PER_PAIR * (DEFAULT_MEMORY_LIMIT // 16)
    rows = []
    for name, (db, q, thr) in _position_sets(scale).items():
        tree = KDTree(db)
        tree.reset_n_calls()
        start = time.perf_counter()
        found = tree.query_radius(q, r=thr)
        seconds = time.perf_counter() - start
        distances, pairs = tree.get_n_calls(), int(sum(f.shape[0] for f in found))
        rows.append({"positions": name, "map": db.shape[0], "queries": q.shape[0], "pairs": pairs,
                     "distances": distances, "per_query": round(distances / q.shape[0], 1),
                     "per_pair": round(distances / max(pairs, 1), 1), "seconds": round(seconds, 2),
                     "distances_per_s": round(distances / seconds),
                     "share_of_default_bound": distances / bound})
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true")
    args = parser.parse_args()
    width, height, scale = (1600, 1200, 0.2) if args.quick else (4000, 3000, 1.0)
    decode = decode_memory(width, height)
    print(f"\n| format ({width}×{height}) | channels × bytes | grey: measured / bound (B/pixel) "
          "| colour: measured / bound |")
    print("|---|---|---|---|")
    for r in decode:
        print(f"| {r['format']} | {r['channels']} × {r['sample_bytes']} | {r['grey_measured_b_per_px']} / "
              f"{r['grey_bound_b_per_px']:g} | {r['colour_measured_b_per_px']} / "
              f"{r['colour_bound_b_per_px']:g} |")
    misses = [r["format"] for r in decode for m in ("grey", "colour")
              if r[f"{m}_measured_b_per_px"] > r[f"{m}_bound_b_per_px"]]
    print(f"\nmeasured above the bound: {', '.join(misses) or 'none'}")
    work = search_work(scale)
    print("\n| positions | map | queries | pairs | distances | per query | per pair | distances/s "
          "| of the bound |")
    print("|---|---|---|---|---|---|---|---|---|")
    for r in work:
        print(f"| {r['positions']} | {r['map']} | {r['queries']} | {r['pairs']} | {r['distances']:.3g} | "
              f"{r['per_query']} | {r['per_pair']} | {r['distances_per_s']:.2g} | "
              f"{r['share_of_default_bound']:.2%} |")
    command = " ".join([Path(sys.executable).name, *sys.argv])
    path = write_results("bench_reader_bounds" + ("_quick" if args.quick else ""),
                         {"command": command, "image_size": [width, height], "decode_memory": decode,
                          "search_work": work})
    print(f"\nwritten to {path}")


if __name__ == "__main__":
    main()
