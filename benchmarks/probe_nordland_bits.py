"""Probes of why BTEL's bits do not transfer from summer to winter on nordland64 (HOG).

Three measurements quoted in ``docs/reading.md``, each on summer map → winter queries, recall@10
(tolerance 10 frames) and per-bit balanced accuracy of BTE-C:

1. **Few columns** — BTE-C with d' = 8, 32, 128 columns and C = 1 or 0.01 at N = 3576: with no
   room to memorise the map, do the bits transfer?
2. **Augmented map** — the first ``--aug-frames`` summer frames, each with brightness, contrast and
   shift views (:func:`btel.descriptors.augmented_views`, 7 views per frame), against the plain
   frames, at 32 KB.
3. **Another front end** — DenseVLAD (learnt on the summer map) instead of HOG: brute force and
   BTE-C at 64 KB.
4. **Within the season** — BTE-C at 64 KB fitted on every other summer frame (place k = frame 2k):
   bit accuracy on the fitted frames, on the next summer frame (2k + 1, held out) and on winter
   frame 2k.

Usage::

    python benchmarks/probe_nordland_bits.py            # ≈ 10 min on 2 cores
    python benchmarks/probe_nordland_bits.py --quick    # first 300 frames

Writes ``benchmarks/results/probe_nordland_bits[_quick].json``.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import write_results  # noqa: E402

from btel import BTELocalizer  # noqa: E402
from btel.descriptors import augmented_views, extract_descriptors, get_descriptor, list_images  # noqa: E402
from btel.methods.btel.diagnostics import localizer_bit_accuracy  # noqa: E402
from btel.methods import make_method  # noqa: E402

ROOT = Path("..") / "shared" / "data" / "nordland64"


def recall10(pred: np.ndarray) -> float:
    return float(np.mean(np.abs(pred - np.arange(len(pred))) <= 10))


def btel_row(model: BTELocalizer, Q: np.ndarray, **extra: Any) -> dict[str, Any]:
    pred = model.predict(Q)
    bits = localizer_bit_accuracy(model, Q, np.arange(len(Q))).balanced
    return {**extra, "bytes": int(model.nbytes), "recall@10": recall10(pred),
            "balanced_bit_accuracy": [round(float(b), 3) for b in bits]}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--data", type=Path, default=ROOT)
    parser.add_argument("--aug-frames", type=int, default=1000)
    parser.add_argument("--quick", action="store_true")
    args = parser.parse_args()
    n = 300 if args.quick else None
    summer = list_images(args.data / "summer")[:n]
    winter = list_images(args.data / "winter")[:n]
    started = time.perf_counter()
    S = extract_descriptors(summer, "hog", progress=False)
    W = extract_descriptors(winter, "hog", progress=False)
    out: dict[str, Any] = {"n_places": len(S)}

    half = len(S) // 2
    fitted_rows, next_rows = np.arange(0, 2 * half, 2), np.arange(1, 2 * half, 2)
    model = BTELocalizer(budget=64_000, progress=False, random_state=0).fit(S[fitted_rows])
    out["within_season"] = {
        name: [round(float(a), 3) for a in localizer_bit_accuracy(model, Q, np.arange(half)).accuracy]
        for name, Q in (("fitted_summer_frames", S[fitted_rows]), ("next_summer_frame", S[next_rows]),
                        ("winter_same_frame", W[fitted_rows]))}
    print("within season", out["within_season"], flush=True)

    out["few_columns"] = []
    for d_sel in (8, 32, 128):
        for C in (1.0, 0.01):
            model = BTELocalizer(n_features=d_sel, C=C, progress=False, random_state=0).fit(S)
            out["few_columns"].append(btel_row(model, W, n_selected=d_sel, C=C))
            print("few columns", out["few_columns"][-1], flush=True)

    m = min(args.aug_frames, len(S))
    views, places = augmented_views(summer[:m], progress=False)
    XA = extract_descriptors(views, "hog", progress=False)
    out["augmented"] = {"frames": m, "views_per_frame": len(views) // m, "budget": 32_000}
    for label, (X, p) in {"plain": (S[:m], None), "augmented": (XA, places)}.items():
        t0 = time.perf_counter()
        model = BTELocalizer(budget=32_000, progress=False, random_state=0).fit(X, p)
        out["augmented"][label] = btel_row(model, W[:m], fit_s=time.perf_counter() - t0)
        print("augmentation", label, out["augmented"][label], flush=True)

    vlad = get_descriptor("densevlad")
    DS = extract_descriptors(summer, vlad, fit_on=summer, progress=False)
    DW = extract_descriptors(winter, vlad, progress=False)
    bf = make_method("bruteforce").fit(DS)
    model = BTELocalizer(budget=64_000, progress=False, random_state=0).fit(DS)
    out["densevlad"] = {"dim": int(DS.shape[1]), "bruteforce_recall@10": recall10(bf.predict(DW)),
                        "btel_c_64KB": btel_row(model, DW)}
    print("densevlad", out["densevlad"], flush=True)

    out["seconds"] = time.perf_counter() - started
    out["command"] = "python benchmarks/probe_nordland_bits.py" + (" --quick" if args.quick else "")
    path = write_results("probe_nordland_bits" + ("_quick" if args.quick else ""), out)
    print(f"written to {path}")


if __name__ == "__main__":
    main()
