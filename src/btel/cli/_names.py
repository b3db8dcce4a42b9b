"""Image names of descriptor rows (:func:`btel.datasets.row_names.row_names`) and hloc retrieval pairs files.

A descriptor matrix written by ``btel extract`` has a JSON sidecar listing its images; an hloc
``.h5`` names every row. Those names let the command line speak the inputs' language: a
VPR-methods-evaluation ground truth from the UTM in the names, and ``--pairs`` files that hloc
reads (``query_name db_name`` per line).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING


if TYPE_CHECKING:  # numpy is imported by the commands that need it: `btel --help` does not wait for it
    import numpy as np

from ..datasets.row_names import row_names  # noqa: F401 (re-exported: the one reader of row names)


def input_names(db: str | None, queries: str, n_map: int, n_queries: int) -> tuple[list[str] | None, list[str] | None]:
    """The image names of the query rows and of the map rows, each None when unknown or not one per row."""
    from ..datasets.vpr_names import check_image_names

    q_names = row_names(queries)
    db_names = row_names(db) if db else None
    q_names = q_names if q_names is not None and len(q_names) == n_queries else None
    db_names = db_names if db_names is not None and len(db_names) == n_map else None
    for option, path, names in (("--queries", queries, q_names), ("--db", db, db_names)):
        if names is not None:  # they go into CSV files, one row per line
            check_image_names(names, f"{option} {path}")
    return q_names, db_names


def pairs_paths(path: str, method_names: Sequence[str]) -> dict[str, Path]:
    """``--pairs FILE``: FILE for a run of one method, else FILE with ``-<method>`` before its suffix."""
    from ..evaluation.runs import safe_file_name

    base = Path(path)
    if len(method_names) == 1:
        return {method_names[0]: base}
    return {m: base.with_name(f"{base.stem}-{safe_file_name(m)}{base.suffix}") for m in method_names}


def plan_pairs(path: str | None, job_names: Sequence[str], names: tuple[list[str] | None, list[str] | None],
               shape: tuple[int, int], queries: str, db: str | None,
               overwrite: bool) -> tuple[dict[str, Path], list[str], list[str]] | None:
    """``--pairs``: (file per row name, query names, map names) — row numbers where the inputs have no
    names, ``shape`` = (queries, map places) — every file refused now when it exists without
    ``--overwrite``; None without ``--pairs``."""
    from ._outputs import OTHER_FORMATS, check_output_suffix, refuse_existing

    if path is None:
        return None
    # A pairs file is text: a name of another format (pr/q.npy) would give text files named .npy.
    check_output_suffix(path, "--pairs", "an hloc pairs file (text)", (".txt",), refused=OTHER_FORMATS)
    targets = pairs_paths(path, job_names)
    for target in targets.values():
        refuse_existing(target, "--pairs", overwrite)
    q_names = names[0] or [str(i) for i in range(shape[0])]
    db_names = names[1] or [str(i) for i in range(shape[1])]
    check_pair_names(q_names, db_names, queries, db)
    return targets, q_names, db_names


def check_pair_names(query_names: Sequence[str], db_names: Sequence[str], queries: str = "--queries",
                     db: str | None = "--db") -> None:
    """Refuse (naming it) an image name that would not stay one field of one line in a pairs file."""
    from ..datasets.vpr_names import check_image_names

    check_image_names(query_names, f"--pairs: --queries {queries}", space=False)
    check_image_names(db_names, f"--pairs: --db {db}", space=False)


def write_pairs(path: Path, ranked: np.ndarray, query_names: Sequence[str], db_names: Sequence[str], *,
                overwrite: bool = True) -> int:
    """An hloc retrieval pairs file: ``query_name db_name`` per line, each query's top K best first.

    Every name is checked first (:func:`check_pair_names`): the file holds exactly one pair per line.
    Written whole or not at all; ``overwrite=False`` keeps a file another process wrote meanwhile
    (:class:`~btel.exceptions.OutputExistsError`)."""
    check_pair_names(query_names, db_names)
    lines = [f"{query_names[i]} {db_names[j]}" for i in range(ranked.shape[0]) for j in ranked[i].tolist()]
    path.parent.mkdir(parents=True, exist_ok=True)
    from ..core.claims import atomic_output

    with atomic_output(path, overwrite=overwrite, text=True) as fh:
        fh.write("\n".join(lines) + "\n")
    return len(lines)


def write_predictions(path: str | Path, predictions: np.ndarray, ranked: np.ndarray | None,
                      query_names: Sequence[str] | None, db_names: Sequence[str] | None, *,
                      overwrite: bool) -> None:
    """``btel localize``'s CSV, the layout of ``btel evaluate``'s (:func:`btel.datasets.predictions.predictions_csv`):
    ``query,prediction``, the image names when known, then ``rank_1 … rank_K`` with a ranking.
    Written whole or not at all; ``overwrite=False`` keeps a file another process wrote meanwhile."""
    from ..core.claims import atomic_output
    from ..datasets.predictions import predictions_csv

    text = predictions_csv(predictions, ranked=ranked, query_names=query_names or None, db_names=db_names or None)
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    with atomic_output(path, overwrite=overwrite, text=True) as fh:
        fh.write(text)
