"""The frontier's journal: ``rows.jsonl``, one row per line as it finishes, read by its progress bar and by ``--resume``.

Every process of ``btel experiment frontier --jobs N`` appends its rows to the one file (one write per
line). :func:`journal_bar` counts its lines for the progress bar; :func:`journalled_rows` reads an
interrupted run's rows back, and a row is reused only where its ``inputs`` (:func:`inputs_digest`: the
map's rows, its queries, the mode and the btel source) are those of the run that resumes.
"""

from __future__ import annotations

import hashlib
import json
import os
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Iterator

import numpy as np

from ..core.limits import open_regular
from ..exceptions import InvalidParameterError
from ._common import _source_digest, data_fingerprint

__all__ = ["CHECKSUM", "MAX_JOURNAL_BYTES", "inputs_digest", "journal_bar", "journal_line", "journalled_rows"]

#: Largest journal ``--resume`` reads (a whole run's is about 0.6 MB, its longest line 2 KB).
MAX_JOURNAL_BYTES = 64 << 20
#: The cell of a journal line that holds its row's SHA-1 (:func:`journal_line`).
CHECKSUM = "row_sha1"


def inputs_digest(X: np.ndarray, Q: np.ndarray, quick: bool) -> str:
    """SHA-1 of a map's rows, its queries, the run's mode (quick runs fewer seeds) and the btel source
    that measures them: a journalled row with the same digest is the row this run would measure
    (every row is seeded)."""
    text = f"{data_fingerprint(X)}|{data_fingerprint(Q)}|quick={bool(quick)}|{_source_digest()}"
    return hashlib.sha1(text.encode()).hexdigest()


def journalled_rows(journal: Path) -> dict[str, dict[tuple[Any, ...], dict[str, Any]]]:
    """The rows of an earlier run's journal by inputs digest, then (method label, budget); a line that is
    not such a row (cut short by the interruption, or edited) is left out, and so run again."""
    found: dict[str, dict[tuple[Any, ...], dict[str, Any]]] = {}
    if not journal.exists():  # nothing journalled yet (a FIFO or folder there is refused below)
        return found
    with open_regular(journal) as fh:
        if os.fstat(fh.fileno()).st_size > MAX_JOURNAL_BYTES:
            raise InvalidParameterError(f"{str(journal)!r} holds more than {MAX_JOURNAL_BYTES >> 20} MiB, far more than a "
                                        "frontier run journals: it is not one; run without --resume, or remove it.")
        for line in fh:
            try:
                row = json.loads(line)
            except (ValueError, RecursionError):  # not JSON, or nested past the parser's depth
                continue
            if not isinstance(row, dict) or row.pop(CHECKSUM, None) != _checksum(row):
                continue  # not a row this module wrote, or one edited since
            if (isinstance(row.get("inputs"), str) and isinstance(row.get("method"), str)
                    and type(row.get("budget")) in (int, type(None)) and isinstance(row.get("dataset"), str)):
                found.setdefault(row["inputs"], {})[row["method"], row["budget"]] = row
    return found


def journal_line(row: dict[str, Any]) -> str:
    """One journal line: the row as JSON with its checksum (:data:`CHECKSUM`), so that a row edited or
    damaged since is left out by :func:`journalled_rows` and run again, never published."""
    plain = json.loads(json.dumps(row, default=str))  # what a reader will load (numpy numbers as JSON ones)
    return json.dumps({**plain, CHECKSUM: _checksum(plain)}) + "\n"


def _checksum(row: dict[str, Any]) -> str:
    try:
        text = json.dumps(row, sort_keys=True)
    except (TypeError, ValueError, RecursionError):
        return ""
    return hashlib.sha1(text.encode()).hexdigest()


@contextmanager
def journal_bar(journal: Path, total: int, enabled: bool, *, interval: float = 2.0,
                file: Any = None) -> Iterator[Any]:
    """A progress bar of the rows in ``journal`` (read every ``interval`` s: it counts the rows of every
    process); off when not ``enabled`` or when ``file`` (stderr) is not a terminal. Yields the bar
    (``bar.write`` prints above it)."""
    import threading

    from tqdm.auto import tqdm

    with tqdm(total=total, desc="frontier", unit="row", disable=None if enabled else True, leave=False,
              file=file) as bar:
        stop = threading.Event()

        def watch() -> None:
            while not stop.wait(interval):
                try:
                    with open(journal, "rb") as fh:
                        done = sum(1 for _ in fh)
                except OSError:  # removed or replaced under the run: the bar waits for it
                    continue
                bar.update(max(0, done - bar.n))  # a journal cut short never moves the bar back

        watcher = threading.Thread(target=watch, daemon=True)
        if not bar.disable:
            watcher.start()
        try:
            yield bar
        finally:
            stop.set()
            if watcher.is_alive():
                watcher.join()
