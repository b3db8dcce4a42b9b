"""The report's files: bounded reading, writing that replaces only regular files, and a page never lost.

``btel report`` reads run files of a folder anyone could have edited (each at most a set number of bytes,
a FIFO or device refused before it is waited on) and writes into the documentation folder (regular files
only). Without ``--overwrite`` it refuses a page that would drop sections of the existing one or replace
a full run's section with a quick one: the page is written from the runs of one ``--runs`` folder only,
so a report of a folder holding one quick run (``btel experiment accuracy --quick``, as the reproducing
guide suggests for a first look) would otherwise replace the published page of every experiment, silently.
"""

from __future__ import annotations

import json
import os
import stat
from pathlib import Path
from typing import Any, Mapping

from ..exceptions import DataNotFoundError, InvalidParameterError, OutputExistsError

__all__ = ["MAX_TEXT_BYTES", "check_nothing_lost", "check_target", "read_bytes", "read_text", "write_bytes"]

#: Largest results.json / results.md / reading.md read (16 MiB; the full runs' files are well under 1 MiB).
MAX_TEXT_BYTES = 16 << 20


def read_bytes(path: Path, limit: int) -> bytes:
    """The bytes of the regular file ``path`` (a symlink to one is followed), at most ``limit`` of them.

    Raises
    ------
    DataNotFoundError
        ``path`` cannot be opened.
    InvalidParameterError
        ``path`` is not a regular file (a device, FIFO, socket or folder), or holds more than ``limit`` bytes.
    """
    try:  # O_NONBLOCK: opening a FIFO must not wait for a writer; fstat then refuses it
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0))
    except OSError as exc:
        raise DataNotFoundError(f"{str(path)!r} could not be opened: {exc.strerror}.") from exc
    if not stat.S_ISREG(os.fstat(fd).st_mode):  # checked before fdopen, which refuses a folder on its own terms
        os.close(fd)
        raise InvalidParameterError(f"{str(path)!r} is not a regular file (a device, FIFO, socket or folder); "
                                    "btel report reads and copies files only: remove it or replace it by a file.")
    with os.fdopen(fd, "rb") as fh:
        data = fh.read(limit + 1)  # one byte more than allowed: a file larger than its stat (or growing) is caught
    if len(data) > limit:
        raise InvalidParameterError(f"{str(path)!r} holds more than {limit} bytes, more than btel report reads "
                                    "from one file; it is not an experiment's output.")
    return data


def read_text(path: Path) -> str:
    """UTF-8 text of a regular file of at most :data:`MAX_TEXT_BYTES` bytes (see :func:`read_bytes`)."""
    try:
        return read_bytes(path, MAX_TEXT_BYTES).decode("utf-8")
    except UnicodeDecodeError as exc:
        raise InvalidParameterError(f"{str(path)!r} is not UTF-8 text ({exc.reason} at byte {exc.start}).") from exc


def check_target(path: Path, force: bool = False) -> None:
    """Refuse an output path that exists and is not a regular file (always, with ``force``)."""
    if force or (os.path.lexists(path) and not path.is_file()):
        raise InvalidParameterError(f"{str(path)!r} exists and is not a regular file (a device, FIFO, socket, "
                                    "folder or dangling link); btel report writes files only: remove it.")


def write_bytes(path: Path, data: bytes) -> None:
    """Replace the content of ``path``: a new file, or an existing regular file (a symlink to one is followed).

    Raises
    ------
    InvalidParameterError
        ``path`` exists and is not a regular file (a device, FIFO, socket, folder or dangling symlink):
        refused before it is opened.
    """
    check_target(path)
    # No O_TRUNC at open: a FIFO or device swapped in since the check is refused by fstat before any change.
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | getattr(os, "O_NONBLOCK", 0), 0o666)
    if not stat.S_ISREG(os.fstat(fd).st_mode):
        os.close(fd)
        check_target(path, force=True)
    with os.fdopen(fd, "wb") as fh:
        os.ftruncate(fd, 0)
        fh.write(data)


def check_nothing_lost(json_path: Path, payloads: Mapping[str, Mapping[str, Any]], generated: str = "") -> None:
    """Refuse a report that would drop or downgrade sections of the page recorded in ``json_path``.

    Parameters
    ----------
    json_path : Path
        The existing ``results.json`` (``{experiment: {"run": {...}, ...}}``); nothing is checked when it
        does not exist or cannot be read as such (the caller has checked that btel report wrote it).
    payloads : mapping
        The new runs' results by experiment name, each with its ``run`` object (``quick`` a bool).
    generated : str
        The line that marks a results.md as a reported page: such a page without its results.json is
        refused too (a results.md of marker blocks only, which benchmark scripts maintain, is not).

    Raises
    ------
    OutputExistsError
        The new page would leave out experiments the old one holds, or put a quick run where a full one was;
        the message names them, and the two ways on (``--docs`` elsewhere, or ``--overwrite``).
    """
    if not json_path.is_file():
        page = json_path.parent / "results.md"  # a reported page without its record: what it holds is unknown
        if generated and page.is_file() and generated in read_text(page):
            raise OutputExistsError(
                f"{str(json_path.parent)!r} holds a results.md without the results.json that records its sections, so "
                "what this report would drop cannot be checked. Give --docs another folder, or --overwrite to replace "
                "the page.")
        return
    try:
        old = json.loads(read_text(json_path))
    except (ValueError, RecursionError, DataNotFoundError):
        return
    if not isinstance(old, dict):
        return
    dropped = [name for name in old if name not in payloads]
    full = {name for name, section in old.items()
            if isinstance(section, dict) and isinstance(section.get("run"), dict) and not section["run"].get("quick")}
    downgraded = [name for name, payload in payloads.items() if name in full and payload["run"].get("quick")]
    if not dropped and not downgraded:
        return
    losses = []
    if dropped:
        losses.append(f"drop the sections of {', '.join(dropped)} (not among these runs)")
    if downgraded:
        losses.append(f"replace the full run{'s' if len(downgraded) > 1 else ''} of {', '.join(downgraded)} with "
                      "quick-mode results")
    raise OutputExistsError(
        f"{str(json_path.parent)!r} holds a results page that this report would {' and '.join(losses)}; the page "
        "is written from the --runs folder alone. Give --docs another folder to look at these runs, or --overwrite "
        "to replace the page with them.")
