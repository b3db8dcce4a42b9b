"""Throughput of the image front ends (btel.descriptors): images per second, from image files.

Datasets (real, from ../shared/data): the first ``--nordland`` Nordland summer frames (64×32 PNG)
and the 20 Gardens Point sample images (640×360 JPEG, 10 ref + 10 query). DenseVLAD learns its
vocabulary and PCA on the map (Nordland: the same frames; Gardens Point: the 10 ref images), and
that fit is timed separately. Transform time includes decoding the files; the ``read`` row is
decoding alone, for reference. Each transform is timed ``--repeat`` times after a one-image
warm-up; the best run is reported.

    python benchmarks/bench_descriptors.py            # 300 Nordland frames, K = 128
    python benchmarks/bench_descriptors.py --quick    # 60 frames, K = 32, one repeat

Writes benchmarks/results/bench_descriptors.json and .csv (machine info in the JSON).
"""

from __future__ import annotations

import argparse
import csv
import os
import time
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import skimage

from btel.descriptors import get_descriptor, list_images, read_image

from _common import RESULTS_DIR, write_results

DEFAULT_DATA = Path(os.environ.get("BTEL_SHARED_DATA", Path(__file__).resolve().parents[2] / "shared" / "data"))
FIELDS = ["dataset", "descriptor", "n_images", "image_size", "dim", "fit_seconds", "transform_seconds", "images_per_second"]


def best_of(repeat: int, fn) -> tuple[float, Any]:
    """Smallest wall time of ``repeat`` calls of ``fn`` and the last result."""
    best, result = float("inf"), None
    for _ in range(repeat):
        start = time.perf_counter()
        result = fn()
        best = min(best, time.perf_counter() - start)
    return best, result


def bench_dataset(name: str, images: list[Path], map_images: list[Path], args: argparse.Namespace) -> list[dict]:
    height, width = read_image(images[0], grey=True).shape
    rows = []
    seconds, _ = best_of(args.repeat, lambda: [read_image(p, grey=True) for p in images])
    rows.append(dict(dataset=name, descriptor="read", n_images=len(images), image_size=f"{width}x{height}",
                     dim=None, fit_seconds=0.0, transform_seconds=seconds, images_per_second=len(images) / seconds))
    for key, params in (("hog", {}), ("patchnorm", {}), ("densevlad", {"n_clusters": args.k})):
        descriptor = get_descriptor(key, **params)
        start = time.perf_counter()
        descriptor.fit(map_images, progress=False)
        fit_seconds = time.perf_counter() - start
        descriptor.transform(images[:1], progress=False)  # warm-up (caches, lazy imports)
        seconds, X = best_of(args.repeat, lambda: descriptor.transform(images, progress=False))
        if not np.isfinite(X).all():
            raise RuntimeError(f"{key} produced non-finite descriptors on {name}")
        rows.append(dict(dataset=name, descriptor=key, n_images=len(images), image_size=f"{width}x{height}",
                         dim=int(X.shape[1]), fit_seconds=fit_seconds if descriptor.requires_fit else 0.0,
                         transform_seconds=seconds, images_per_second=len(images) / seconds))
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--data", type=Path, default=DEFAULT_DATA, help="the shared data folder")
    parser.add_argument("--nordland", type=int, default=300, help="Nordland summer frames to describe")
    parser.add_argument("--k", type=int, default=128, help="DenseVLAD vocabulary size")
    parser.add_argument("--repeat", type=int, default=3, help="timed transform runs (best reported)")
    parser.add_argument("--quick", action="store_true", help="60 frames, K = 32, one repeat")
    args = parser.parse_args()
    if args.quick:
        args.nordland, args.k, args.repeat = 60, 32, 1

    nordland = list_images(args.data / "nordland64" / "summer")[: args.nordland]
    gardens_ref = list_images(args.data / "gardenspoint_sample" / "ref")
    gardens_all = gardens_ref + list_images(args.data / "gardenspoint_sample" / "query")

    rows = bench_dataset("nordland64", nordland, nordland, args)
    rows += bench_dataset("gardenspoint_sample", gardens_all, gardens_ref, args)

    print(f"{'dataset':<20} {'descriptor':<10} {'n':>4} {'size':>8} {'dim':>5} {'fit s':>7} {'img/s':>9}")
    for r in rows:
        dim = "" if r["dim"] is None else r["dim"]
        print(f"{r['dataset']:<20} {r['descriptor']:<10} {r['n_images']:>4} {r['image_size']:>8} {dim:>5} "
              f"{r['fit_seconds']:>7.2f} {r['images_per_second']:>9.1f}")

    config = {"nordland_frames": args.nordland, "densevlad_k": args.k, "repeat": args.repeat, "quick": args.quick,
              "opencv": cv2.__version__, "scikit-image": skimage.__version__, "opencv_threads": cv2.getNumThreads(),
              **{k: os.environ[k] for k in ("OMP_NUM_THREADS", "OMP_WAIT_POLICY") if k in os.environ}}
    path = write_results("bench_descriptors", {"config": config, "results": rows})
    with open(RESULTS_DIR / "bench_descriptors.csv", "w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=FIELDS)
        writer.writeheader()
        writer.writerows(rows)
    print(f"wrote {path} and {path.with_suffix('.csv')}")


if __name__ == "__main__":
    main()
