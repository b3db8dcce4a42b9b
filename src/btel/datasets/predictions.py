"""The predictions CSV ``btel evaluate`` writes for each row and ``btel localize`` writes for its queries:
one layout, one writer (:func:`predictions_csv`). Light on purpose: answering a query file imports nothing
that evaluating needs."""

from __future__ import annotations

import csv
import io
from collections.abc import Sequence
from typing import Any

import numpy as np

from .vpr_names import check_image_names

__all__ = ["predictions_csv"]


def predictions_csv(predictions: Any, *, ranked: Any = None, ground_truth: Any = None,
                    query_names: Sequence[str] | None = None, db_names: Sequence[str] | None = None) -> str:
    """One predictions CSV for ``btel evaluate`` and ``btel localize``: one row per query.

    Columns: ``query,prediction``; ``true`` (one true place per query) or ``positive`` (one of the
    query's positives, -1 for none) and ``correct`` (0/1, the top-1 is a true place) when the
    ground truth is known; when the inputs name their rows (``btel extract``'s .json, hloc .h5),
    ``query_name``, ``prediction_name`` and ``true_name`` / ``positive_name``; then ``rank_1…rank_K``
    when a ranking is given. Row numbers always stay.
    """
    predictions = np.asarray(predictions)
    n = predictions.shape[0]
    columns: list[tuple[str, Sequence[Any]]] = [("query", np.arange(n)), ("prediction", predictions)]
    gt = ground_truth
    reference = None
    if gt is not None and gt.kind == "places":
        reference = ("true", np.asarray(gt.query_places))
    elif gt is not None:
        first = np.full(n, -1, dtype=np.int64) if gt.indices.size == 0 else \
            np.where(np.diff(gt.indptr) > 0, gt.indices[np.minimum(gt.indptr[:-1], gt.indices.size - 1)], -1)
        reference = ("positive", first)
    if reference is not None:
        columns.append(reference)
        columns.append(("correct", gt.is_correct(predictions).astype(np.int64)))
    if query_names is not None and len(query_names) == n:
        check_image_names(query_names, "query names")  # one CSV row per line
        columns.append(("query_name", list(query_names)))
    if db_names is not None:
        check_image_names(db_names, "map names")
        named = np.asarray(list(db_names) + [""], dtype=object)  # -1 (no place) → ""
        columns.append(("prediction_name", named[predictions]))
        if reference is not None:
            columns.append((f"{reference[0]}_name", named[reference[1]]))
    if ranked is not None:
        columns += [(f"rank_{j + 1}", ranked[:, j]) for j in range(ranked.shape[1])]
    buffer = io.StringIO()
    out = csv.writer(buffer, lineterminator="\n")
    out.writerow([name for name, _ in columns])
    for i in range(n):
        out.writerow([int(v[i]) if isinstance(v, np.ndarray) and v.dtype.kind in "iub" else v[i] for _, v in columns])
    return buffer.getvalue()
