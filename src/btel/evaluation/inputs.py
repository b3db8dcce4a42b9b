"""What a run of several methods is measured on: saved models beside fitted ones, one map, a title.

``btel evaluate`` parses its options and calls these, then :func:`btel.evaluation.run_methods`.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from ..core.storage import format_bytes, parse_budget
from ..exceptions import InvalidParameterError
from .batch import Job

__all__ = ["saved_jobs", "common_map_size", "run_title"]


def saved_jobs(paths: Sequence[str | os.PathLike], n_features: int) -> list[Job]:
    """One ``fit=False`` job per saved model file (named by the file), checked against the queries' width.

    Raises
    ------
    InvalidParameterError
        A model fitted on descriptors of another dimension.
    """
    from ..methods.registry import load

    jobs = []
    for path in paths:
        model = load(path)
        if model.n_features_in_ != n_features:
            raise InvalidParameterError(f"model {path} expects {model.n_features_in_}-D descriptors but the "
                                        f"queries have {n_features}.")
        jobs.append(Job(Path(path).name.split(".")[0], model, fit=False))
    return jobs


def common_map_size(X_map: Any, Q: Any, saved: Sequence[Job]) -> int:
    """The number of map places the map descriptors and every saved model share.

    Raises
    ------
    InvalidParameterError
        The map and queries differ in width, or the maps differ in size (one ground truth could
        not hold for all).
    """
    if X_map is not None and X_map.shape[1] != Q.shape[1]:
        raise InvalidParameterError(f"the map has {X_map.shape[1]} dims but the queries have {Q.shape[1]}; "
                                    "describe both with the same descriptor.")
    sizes = {int(job.method.n_places_) for job in saved}
    if X_map is not None:
        sizes.add(int(X_map.shape[0]))
    if len(sizes) != 1:
        raise InvalidParameterError(f"the maps differ in size ({sorted(sizes)} places): the map descriptors "
                                    "and every saved model must cover one map for one ground truth to hold.")
    return sizes.pop()


def run_title(dataset: str, n_map: int, n_queries: int, budgets: Sequence[Any], truth: dict[str, str], *,
              saved: bool = False, fitted: bool = True) -> str:
    """The plots' title: data set, sizes, budgets, ground truth (source and rule)."""
    given = [b for b in budgets if b is not None]
    if given:
        budget = "budget " + ", ".join(format_bytes(parse_budget(b)) for b in given)
    else:
        budget = ("saved models" + (" and unbudgeted methods" if fitted else "")) if saved else "no budget"
    source = truth["source"]
    if source.startswith("frame-aligned"):
        said = "frame-aligned"
    else:
        said = (f"{truth['rule']} from {Path(source).name}" if os.path.isabs(source)
                else f"{truth['rule']} ({source})")
    return f"{dataset}: N = {n_map}, {n_queries} queries; {budget}; {said}"
