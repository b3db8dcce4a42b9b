"""Going on with an interrupted run (``btel evaluate --resume RUN``), and the inputs it must still see.

A run folder's ``metrics.json`` records, besides its rows, a fingerprint of every input file
(:func:`input_fingerprints`: SHA-256 and size of each file, of every file of a folder of shards):
a resumed run whose map, queries, ground truth, calibration files or saved models changed since the
run started is refused (:func:`changed_inputs`), since its new rows would be measured on other data
than the rows already done. The run's first command line and date stay in the metadata; each
resume is listed under ``"resumed"`` with its own command, date and versions.
"""

from __future__ import annotations

import hashlib
import os
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from .records import EvaluationResult
from .runs import _LOCK_NAME, RunWriter, run_metadata, safe_file_name
from ..core.fingerprint import feed_file
from ..core.modelfile import jsonable
from ..exceptions import DataNotFoundError, InvalidParameterError

__all__ = ["read_unfinished_run", "check_finished_rows", "resume_writer", "input_fingerprints", "changed_inputs"]


def fingerprint(text: str) -> dict[str, Any] | None:
    """SHA-256 and size of the input a command line names (``PATH``, ``PATH.npz:KEY``, ``PATH.h5:PREFIX``
    or a folder of shards: every regular file in it, by name); None for a name that is no file
    (``utm``, the frame-aligned default) or a file that cannot be read now."""
    from ..descriptors.npy import split_prefix

    path = Path(text)
    if not path.exists():
        path = split_prefix(text)[0]
    digest = hashlib.sha256()
    try:
        if path.is_dir():
            size = 0
            for entry in sorted(p for p in path.iterdir() if not p.name.startswith(".") and p.is_file()):
                digest.update(entry.name.encode("utf-8", "surrogateescape") + b"\0")
                size += feed_file(entry, digest)
        elif path.is_file():
            size = feed_file(path, digest)
        else:
            return None
    except OSError:
        return None
    return {"sha256": digest.hexdigest(), "bytes": size}


def input_fingerprints(inputs: Mapping[str, str | Sequence[str] | None]) -> dict[str, Any]:
    """``{option: {"path", "sha256", "bytes"}}`` (a list for an option given several files) of the inputs
    that are files; options given nothing, or no file, are left out."""
    out: dict[str, Any] = {}
    for option, given in inputs.items():
        texts = [given] if isinstance(given, str) else list(given or [])
        prints = [{"path": t, **f} for t in texts if (f := fingerprint(t)) is not None]
        if prints:
            out[option] = prints[0] if isinstance(given, str) else prints
    return out


def changed_inputs(recorded: Mapping[str, Any], current: Mapping[str, Any]) -> list[str]:
    """The options whose files differ between a run's ``recorded`` fingerprints and the ``current`` ones
    (a file gone, added, or with other bytes)."""

    def digests(entry: Any) -> list[Any]:
        items = entry if isinstance(entry, list) else [entry]
        return [(i.get("sha256"), i.get("bytes")) if isinstance(i, Mapping) else i for i in items]

    return [option for option in sorted({*recorded, *current})
            if digests(recorded.get(option, [])) != digests(current.get(option, []))]


def read_unfinished_run(out_dir: str | os.PathLike) -> tuple[dict[str, Any], list[EvaluationResult]]:
    """The run metadata and rows of a run folder, to go on with it (``btel evaluate --resume RUN``).

    Raises
    ------
    DataNotFoundError
        No ``metrics.json`` in ``out_dir``.
    InvalidParameterError
        ``metrics.json`` is not a btel run (too large, not JSON, nested too deep, or rows without their
        fields); the message names the file and the fix.
    """
    from .runfile import read_run_payload

    path = Path(out_dir) / "metrics.json"
    if not os.path.lexists(path):  # a FIFO or folder there is refused by the reader, never waited on
        raise DataNotFoundError(f"{str(out_dir)!r} has no metrics.json; it is not a run folder to resume.")
    fix = "run the evaluation again without --resume (into a new --out folder)"
    run, results = read_run_payload(path, fix)
    try:
        return run, [EvaluationResult.from_dict(r) for r in results]
    except InvalidParameterError as exc:
        raise InvalidParameterError(f"{str(path)!r} is not a btel run's metrics ({exc}); {fix}.") from exc


def check_finished_rows(run: str | os.PathLike, rows: Sequence[EvaluationResult], jobs: Sequence[Any],
                        echo: Any = None) -> list[EvaluationResult]:
    """The rows of the interrupted run ``run`` to keep (status ok), after checking that the ``jobs`` of
    the resumed run are its jobs; ``echo(text)`` hears which rows are done.

    Raises
    ------
    InvalidParameterError
        A row of the run is no job (it would be dropped), or a row done has another budget or
        ``--param`` settings than its job (it would be mixed with rows of other settings).
    """
    by_name = {job.name: job for job in jobs}
    settings = {n: (jsonable(j.settings) if j.settings else None) for n, j in by_name.items()}
    lost = [r.name for r in rows if r.name not in by_name]
    other = [r.name for r in rows if r.ok and r.name in by_name and by_name[r.name].fit
             and (r.budget != by_name[r.name].budget or r.settings != settings[r.name])]
    if lost or other:
        raise InvalidParameterError(
            f"the run {str(run)!r} has rows {lost or other} that these methods and options "
            f"{'do not make' if lost else 'make with another budget or --param'}; give the interrupted run's "
            "options (or none beside --resume), or start a new run with --out.")
    done = [r for r in rows if r.ok]
    if echo is not None:
        echo(f"resuming {run}: {len(done)} of {len(jobs)} rows done ({', '.join(r.name for r in done) or 'none'}); "
             "the others run now")
    return done


def resume_writer(out_dir: str | os.PathLike, finished: Sequence[EvaluationResult], *,
                  command: str | Sequence[str] | None = None, extra: Mapping[str, Any] | None = None) -> RunWriter:
    """A :class:`~btel.evaluation.runs.RunWriter` that goes on writing into an existing run folder: the
    predictions files of the ``finished`` rows are kept (not rewritten), everything else is rewritten as
    the run goes on. The metadata keeps the run's first command and date and lists this resume."""
    from ..core.claims import claim

    writer = RunWriter.__new__(RunWriter)
    writer.out_dir = Path(out_dir)
    # The same claim as a new run's: a second run (or a second --resume) into this folder waits its turn.
    writer._lock = claim(writer.out_dir, _LOCK_NAME)
    try:
        previous = read_unfinished_run(writer.out_dir)[0]
    except (DataNotFoundError, InvalidParameterError):
        previous = {}
    now = run_metadata(command)
    resumed = previous.get("resumed") if isinstance(previous.get("resumed"), list) else []
    writer.meta = {**now, **{k: v for k, v in previous.items() if k not in ("complete", "extra")},
                   "resumed": [*resumed, {k: now[k] for k in ("command", "cwd", "date_utc", "btel_commit",
                                                              "versions")}]}
    if extra:
        writer.meta["extra"] = jsonable(dict(extra))
    writer.metrics_json = writer.out_dir / "metrics.json"
    writer.metrics_csv = writer.out_dir / "metrics.csv"
    writer.predictions = {r.name: writer.out_dir / f"predictions_{safe_file_name(r.name)}.csv"
                          for r in finished if r.ok}
    writer.plots = []
    writer.query_names = writer.db_names = None
    writer._started = time.monotonic()  # the run's "seconds" are then this resume's
    return writer
