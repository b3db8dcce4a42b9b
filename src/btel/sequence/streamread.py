"""Readers of a descriptor stream: text lines as they arrive, or binary float32 frames.

:func:`read_lines` reads any text or binary stream line by line (a file, followed as it grows, or a
pipe). :func:`chunk_lines` reads a binary file or pipe in chunks and, on a pipe, also says when no
further line is waiting (:data:`IDLE`): the caller answers what it holds before the read that would
block, so a fast producer's lines are answered in blocks and a camera's frame as soon as it arrives.
Only whole lines are answered: a last line without its newline (a producer that stopped in the middle
of a line) is a :class:`CutLine`, reported, never parsed, since ``…e-0`` cut from ``…e-01`` still reads
as a number.

**Binary frames** (``btel localize --stream --binary``; :func:`read_frames`): each frame is a
little-endian ``uint32`` count n, then n little-endian ``float32`` values — in numpy
``np.uint32(d).tobytes() + x.astype("<f4").tobytes()``. n = d is a descriptor; n = 0 starts a new
traverse (like a ``reset`` line); any other n is a malformed frame, reported and skipped. A count
beyond the line limit (``$BTEL_MAX_LINE_BYTES``) means the input is not frames or lost its framing:
the stream stops with :class:`~btel.exceptions.InvalidDescriptorsError`; so does a frame cut short
by the end of the input.
"""

from __future__ import annotations

import os
import select
import stat
import time
import warnings
from typing import Any, BinaryIO, Iterator

import numpy as np

from ..exceptions import InvalidDescriptorsError
from .lineparse import LineTooLong, max_line_bytes

__all__ = ["read_lines", "chunk_lines", "read_frames", "is_pipe", "IDLE", "RESET", "BadFrame", "CutLine"]

#: Yielded by :func:`chunk_lines` and :func:`read_frames` when no further input is waiting.
IDLE = object()
#: Yielded by :func:`read_frames` for a frame of 0 values: a new traverse starts.
RESET = "reset"


class BadFrame:
    """Stands for a binary frame that is not a descriptor (reported, then skipped)."""

    def __init__(self, message: str) -> None:
        self.text = message

    def message(self) -> str:
        return self.text


class CutLine:
    """Stands for the last line of an input that ended without its newline (reported, not answered):
    a producer that stopped mid-line leaves a line that may still hold the right number of values
    (``…e-0`` of ``…e-01``), so it cannot be told from a whole one."""

    def __init__(self, carriage_returns: bool = False) -> None:
        self.carriage_returns = carriage_returns

    def message(self) -> str:
        if self.carriage_returns:  # classic Mac line ends: the whole input reads as one line
            return ("the input ended inside this line (no newline after it), and it holds carriage returns: its "
                    "lines end in CR alone (old Mac text), which is not a line end here; convert them "
                    "(`tr '\\r' '\\n' < IN > OUT`) or write lines ending in LF or CRLF.")
        return ("the input ended inside this line (no newline after it): a line cut short can look whole, so "
                "it is not answered; end every line with a newline (numpy.savetxt does).")


def _inner_cr(text: str | bytes) -> bool:
    """A carriage return inside the text (not only closing it, as a CRLF line whose LF is missing ends)."""
    cr, ends = ("\r", "\r\n") if isinstance(text, str) else (b"\r", b"\r\n")
    return cr in text.rstrip(ends)


def is_pipe(stream: Any) -> bool:
    """True for a binary stream on a pipe, socket or terminal that can be polled (POSIX select)."""
    try:
        mode = os.fstat(stream.fileno()).st_mode
    except (OSError, ValueError, AttributeError):
        return False
    return (os.name == "posix" and hasattr(stream, "read1") and not hasattr(stream, "encoding")
            and (stat.S_ISFIFO(mode) or stat.S_ISSOCK(mode) or stat.S_ISCHR(mode)))


def _widen_pipe(fd: int) -> None:
    """Ask Linux for a 1 MiB pipe buffer (the unprivileged maximum by default; 64 KiB otherwise).

    A producer faster than btel then runs up to 1 MiB ahead (80 lines of savetxt at d = 500, not 5),
    so a backlog is read in fewer calls and answered in larger blocks. Anything that refuses (not
    Linux, not a FIFO, a lower ``pipe-max-size``) leaves the pipe as it was."""
    try:
        import fcntl

        if fcntl.fcntl(fd, getattr(fcntl, "F_GETPIPE_SZ", 1032)) < 1 << 20:  # never shrink it
            fcntl.fcntl(fd, getattr(fcntl, "F_SETPIPE_SZ", 1031), 1 << 20)
    except (OSError, ImportError, ValueError):
        pass


def _waiting(fd: int) -> bool:
    return bool(select.select([fd], [], [], 0)[0])


def read_lines(stream: Any, *, follow: bool = False, poll_interval: float = 0.1,
               idle_timeout: float | None = None, max_line: int | None = None) -> Iterator[Any]:
    """Yield complete lines from ``stream`` as they arrive (a :class:`LineTooLong` for each over-long one).

    Parameters
    ----------
    stream : text or binary file
        A pipe (stdin) or a file. A pipe blocks until its next line; a file ends at EOF. A binary
        stream yields bytes lines (decoded one line at a time by the caller, so a byte that is not
        UTF-8 spoils only its own line).
    follow : bool
        Keep reading a file as it grows (``tail -f``): at EOF, wait ``poll_interval`` seconds and
        try again. A line without its newline yet is held back until it is complete.
        At the end of the input (or of ``idle_timeout``) a last line without its newline comes out
        as a :class:`CutLine`: the producer may have stopped in the middle of it.
    idle_timeout : float, optional
        With ``follow``, stop after this many seconds without new data (default: never).
    max_line : int, optional
        Longest line in bytes (characters for a text stream), newline excluded; default
        :func:`~btel.sequence.lineparse.max_line_bytes`. At most this much of a line is held in memory: a
        longer one is read through and replaced by a :class:`LineTooLong`.
    """
    limit = max_line_bytes() if max_line is None else int(max_line)
    pending: Any = None
    skipping = False  # inside a line longer than the limit: read on to its end, keep nothing
    last_data = time.monotonic()
    while True:
        chunk = stream.readline(limit + 1 - (len(pending) if pending is not None else 0))
        if chunk:
            last_data = time.monotonic()
            complete = chunk.endswith(b"\n" if isinstance(chunk, bytes) else "\n")
            if skipping:
                if complete:
                    skipping = False
                    yield LineTooLong(limit)
                continue
            pending = chunk if pending is None else pending + chunk
            if complete and len(pending) <= limit + 1:
                yield pending
                pending = None
            elif len(pending) > limit:
                pending = None
                if complete:
                    yield LineTooLong(limit)
                else:
                    skipping = True
            continue
        if not follow or (idle_timeout is not None and time.monotonic() - last_data >= idle_timeout):
            break
        if _truncated(stream):  # as `tail -f` does: say so, and read the file again from its start
            size, read = os.fstat(stream.fileno()).st_size, stream.tell()
            warnings.warn(f"{getattr(stream, 'name', 'the input')} was truncated (it holds {size} bytes; {read} were "
                          "read): reading it again from its start", stacklevel=2)
            stream.seek(0)
            pending, skipping = None, False
            continue
        time.sleep(poll_interval)
    if skipping:
        yield LineTooLong(limit)
    elif pending and pending.strip():
        # the last line lacks its newline: cut short, or not, cannot be told
        yield CutLine(_inner_cr(pending))


def _truncated(stream: Any) -> bool:
    """A followed binary file now shorter than what was read of it (rewritten or emptied by its producer)."""
    if hasattr(stream, "encoding"):  # a text stream's tell() is an opaque cookie, not a byte offset
        return False
    try:
        return os.fstat(stream.fileno()).st_size < stream.tell()
    except (OSError, ValueError, AttributeError):
        return False


def chunk_lines(stream: BinaryIO, *, max_line: int | None = None) -> Iterator[Any]:
    """The lines of a binary stream read in chunks (bytes, or :class:`LineTooLong`); on a pipe
    (:func:`is_pipe`) also :data:`IDLE` before each read that would wait.

    Reads whatever has arrived (``read1``, up to 1 MiB; a pipe is first widened to 1 MiB where Linux allows) and splits
    it into lines itself — no call per line — so on a pipe it knows when its buffer holds no whole
    line and the pipe has nothing more (``select``): then it yields :data:`IDLE`. Line limits as
    :func:`read_lines`; ends at the end of the input (a last line without its newline: :class:`CutLine`).
    """
    limit = max_line_bytes() if max_line is None else int(max_line)
    fd = stream.fileno() if is_pipe(stream) else None
    read = getattr(stream, "read1", stream.read)
    size = 1 << 20
    if fd is not None:
        _widen_pipe(fd)
    buf = b""
    skipping = False
    first = True  # the stream's own buffer may hold bytes read before: read them without asking the pipe
    while True:
        start = 0
        while (end := buf.find(b"\n", start)) >= 0:
            yield LineTooLong(limit) if end - start > limit else buf[start:end + 1]
            start = end + 1
        buf = buf[start:]
        if len(buf) > limit:  # no newline within the limit: drop this line as it goes by
            buf, skipping = b"", True
        if fd is not None and not first and not _waiting(fd):
            yield IDLE
        first = False
        chunk = read(size)
        if not chunk:
            break
        if skipping:
            end = chunk.find(b"\n")
            if end < 0:
                continue
            yield LineTooLong(limit)
            chunk, skipping = chunk[end + 1:], False
        buf += chunk
    if skipping:
        yield LineTooLong(limit)
    elif buf.strip():
        yield CutLine(_inner_cr(buf))


def _count_hint(head: bytes, n_features: int) -> str:
    """What a frame count that makes no sense most likely is: text, or a big-endian count."""
    if int.from_bytes(head, "big") == n_features:
        return f" (a big-endian count of {n_features}? frames are little-endian: write them as '<u4' and '<f4')"
    if all(32 <= b < 127 or b in b"\t\r\n" for b in head):
        return f" (its bytes {head!r} are text: text lines are read without --binary)"
    return ""


def read_frames(stream: BinaryIO, n_features: int, *, follow: bool = False, poll_interval: float = 0.1,
                idle_timeout: float | None = None) -> Iterator[Any]:
    """The binary frames of ``stream`` (module docstring): a (1, d) float32 row per descriptor,
    :data:`RESET`, :class:`BadFrame`, and :data:`IDLE` when a pipe has nothing more waiting.

    Raises
    ------
    InvalidDescriptorsError
        A frame count beyond the limit (not frames, or framing lost), or a frame cut short by the end.
    """
    limit = max_line_bytes()
    fd = stream.fileno() if is_pipe(stream) else None
    number = 0
    last_data = time.monotonic()

    def read(n: int) -> bytes:
        nonlocal last_data
        out = b""
        while len(out) < n:
            chunk = stream.read(n - len(out))
            if chunk:
                out += chunk
                last_data = time.monotonic()
            elif not follow or (idle_timeout is not None and time.monotonic() - last_data >= idle_timeout):
                return out
            else:
                time.sleep(poll_interval)
        return out

    while True:
        if fd is not None and not _waiting(fd):
            yield IDLE
        head = read(4)
        if not head:
            return
        number += 1
        count = int.from_bytes(head.ljust(4, b"\0"), "little")
        if len(head) < 4 or count * 4 > limit:
            what = (f"the input ends inside its 4-byte count ({len(head)} bytes)" if len(head) < 4 else
                    f"its count {count} values ({count * 4} bytes) exceeds the {limit}-byte limit "
                    f"($BTEL_MAX_LINE_BYTES){_count_hint(head, n_features)}")
            raise InvalidDescriptorsError(
                f"frame {number}: {what}; binary frames are a little-endian uint32 count then that many "
                "float32 values: the input is not btel frames, or lost its framing.")
        payload = read(4 * count)
        if len(payload) < 4 * count:
            raise InvalidDescriptorsError(f"frame {number}: the input ends after {len(payload)} of its "
                                          f"{4 * count} bytes (a frame cut short).")
        if count == 0:
            yield RESET
        elif count != n_features:
            yield BadFrame(f"a frame of {count} values; the model takes {n_features}.")
        else:
            row = np.frombuffer(payload, dtype="<f4").astype(np.float32).reshape(1, -1)
            square = float(np.dot(row[0].astype(np.float64), row[0]))
            if not np.isfinite(row).all():
                yield BadFrame(f"value {int(np.flatnonzero(~np.isfinite(row[0]))[0]) + 1} is not finite.")
            elif not square <= float(np.finfo(np.float32).max):
                yield BadFrame(f"the values are too large: their squared norm ({square:.3g}) overflows "
                               "float32.")
            else:
                yield row
