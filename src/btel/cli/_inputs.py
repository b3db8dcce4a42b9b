"""Reading descriptor matrices named on the command line: .npy, .npz[:KEY], hloc .h5[:PREFIX], shard folders."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import click

if TYPE_CHECKING:  # numpy is imported by the commands that need it: `btel --help` does not wait for it
    import numpy as np


def _load_matrix(path: str, what: str) -> np.ndarray:
    from ..descriptors.npy import load_descriptor_matrix

    return _load_whole_h5(path, what) if _is_whole_h5(path) else load_descriptor_matrix(path)


def _is_whole_h5(path: str) -> bool:
    from ..descriptors.npy import HDF5_SUFFIXES, split_prefix

    file, prefix = split_prefix(path)
    return prefix is None and file.suffix.lower() in HDF5_SUFFIXES


def _load_whole_h5(path: str, what: str) -> np.ndarray:
    """An hloc .h5 given without a PREFIX: refused when its images sit under several prefixes (map and
    queries in one file, hloc's usual layout), which would otherwise be read as one set."""
    from ..descriptors.npy import load_hloc_global

    X, names = load_hloc_global(path)
    counts: dict[str, int] = {}
    for name in names:
        head, slash, _ = name.partition("/")
        counts[head + slash] = counts.get(head + slash, 0) + 1
    if len(counts) > 1:
        found = ", ".join(f"{p or '(top level)'} {n} images" for p, n in counts.items())
        choices = " or ".join(f"{path}:{p}" for p in counts if p)
        raise click.UsageError(f"{path} ({what}) holds images under {len(counts)} prefixes ({found}); name the "
                               f"ones you mean, e.g. {choices}.")
    return X


def _load_map(path: str) -> np.ndarray:
    """Map descriptors for training: a folder of .npy shards, a memory-mapped .npy, an .npz or an hloc .h5."""
    if Path(path).is_dir():
        from ..datasets.shards import load_shards

        return load_shards(path)
    if _is_whole_h5(path):
        return _load_whole_h5(path, "map descriptors")
    from ..descriptors.npy import load_descriptor_matrix

    # A .npy map is memory-mapped: pages are read as the fit needs them, never copied whole.
    return load_descriptor_matrix(path, mmap_mode="r" if Path(path).suffix.lower() == ".npy" else None)


def check_calibration_options(method: str, queries: str | None, truth: str | None, tolerance: int | None) -> None:
    """``--calibrate-*`` only with ``--calibrate``, and only for a method whose ``fit`` takes calibration."""
    import inspect

    from ..methods.registry import make_method

    if queries is None and (truth is not None or tolerance is not None):
        raise click.UsageError("--calibrate-truth and --calibrate-tolerance apply with --calibrate QUERIES.")
    if queries is not None and "calibration" not in inspect.signature(make_method(method).fit).parameters:
        raise click.UsageError(f"--calibrate chooses a method on labelled queries, which --method {method} does "
                               "not do. Use --method auto (or compare methods with `btel evaluate`).")


def calibration_input(db: str, queries: str, truth: str | None, n_map: int) -> tuple[np.ndarray, object]:
    """``--calibrate QUERIES --calibrate-truth GT``: the labelled queries and their ground truth (true
    places as an int array, or the :class:`~btel.datasets.GroundTruth` of positives)."""
    from ..datasets.sources import resolve_ground_truth
    from ..evaluation.metrics import check_ground_truth
    from ..exceptions import InvalidParameterError
    from ._errors import InputError

    Q = _load_matrix(queries, "calibration queries")
    try:
        given, _ = resolve_ground_truth(truth, n_queries=Q.shape[0], n_map=n_map, db=db, queries=queries)
    except InvalidParameterError as exc:
        raise InputError(f"--calibrate-truth: {exc}") from None
    gt = check_ground_truth(given, Q.shape[0], n_map, option="--calibrate-truth")
    return Q, (gt.query_places if gt.kind == "places" else gt)
