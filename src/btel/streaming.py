"""Streaming localization: descriptors arrive one per text line, predictions leave one per line.

This is what a robot runs: a camera pipeline writes each frame's global descriptor as a line of
numbers (separated by commas and/or whitespace) to a pipe or an append-only file, and every line
is localized as soon as it is complete, with the paper's sequence filter (SPEC §6) applied across
the stream. The model's front end runs online too (:class:`btel.base.QueryStream`): with delta
descriptors it keeps the last 2w frames and answers from the first frame on (before 2w frames the
missing ones count as copies of the first, so the first answers carry little information). A line
``reset`` starts a new traverse: the filter, the HMM and the delta history forget the past. A malformed line — a wrong number of values, something that is not a number, NaN or
infinity — is reported with its line number and skipped; it does not stop the stream and does
not enter the filter's history.

>>> import io
>>> for line_number, place in localize_stream(model, io.StringIO("0.1,0.2,...\\n")):  # doctest: +SKIP
...     print(place)

``btel localize MODEL --stream [--input FILE [--follow]] [--sequence-filter A]`` is the command-line
front end.
"""

from __future__ import annotations

import re
import time
from typing import Any, Callable, Iterator, TextIO

import numpy as np

from .exceptions import DimensionMismatchError, InvalidDescriptorsError, InvalidParameterError
from .sequence import SequenceFilter

__all__ = ["parse_descriptor_line", "read_lines", "localize_stream", "RESET_LINE"]

#: An input line that starts a new traverse: the sequence filter, the HMM and the front end's
#: delta history forget the past (e.g. the robot was carried to another place).
RESET_LINE = "reset"

_SEPARATORS = re.compile(r"[,\s]+")


def parse_descriptor_line(line: str, n_features: int | None = None) -> np.ndarray:
    """One descriptor from a line of numbers separated by commas and/or whitespace.

    Parameters
    ----------
    line : str
    n_features : int, optional
        Number of values the line must hold (the model's d).

    Returns
    -------
    ndarray of shape (1, n_features), float32

    Raises
    ------
    InvalidDescriptorsError
        Empty line, a value that is not a number, NaN/inf, or the wrong number of values.
    """
    tokens = [t for t in _SEPARATORS.split(line.strip()) if t]
    if not tokens:
        raise InvalidDescriptorsError("empty line (expected one descriptor).")
    if n_features is not None and len(tokens) != n_features:
        raise InvalidDescriptorsError(f"expected {n_features} values, got {len(tokens)}.")
    try:
        values = np.array([float(t) for t in tokens], dtype=np.float64)
    except ValueError:
        bad = next(t for t in tokens if not _is_float(t))
        raise InvalidDescriptorsError(f"{bad[:40]!r} is not a number.") from None
    finite = np.isfinite(values)
    if not finite.all():
        column = int(np.flatnonzero(~finite)[0])
        raise InvalidDescriptorsError(f"value {column + 1} is {tokens[column]!r}; descriptors must be finite.")
    return values.astype(np.float32).reshape(1, -1)


def _is_float(token: str) -> bool:
    try:
        float(token)
    except ValueError:
        return False
    return True


def read_lines(
    stream: TextIO,
    *,
    follow: bool = False,
    poll_interval: float = 0.1,
    idle_timeout: float | None = None,
) -> Iterator[str]:
    """Yield complete lines from ``stream`` as they arrive.

    Parameters
    ----------
    stream : text or binary file
        A pipe (stdin) or a file. A pipe blocks until its next line; a file ends at EOF. A binary
        stream yields bytes lines (decoded one line at a time by :func:`localize_stream`, so a
        byte that is not UTF-8 spoils only its own line).
    follow : bool
        Keep reading a file as it grows (``tail -f``): at EOF, wait ``poll_interval`` seconds and
        try again. A line without its newline yet is held back until it is complete.
    idle_timeout : float, optional
        With ``follow``, stop after this many seconds without new data (default: never; stop
        with Ctrl-C).
    """
    pending: Any = None
    last_data = time.monotonic()
    while True:
        chunk = stream.readline()
        if chunk:
            last_data = time.monotonic()
            pending = chunk if pending is None else pending + chunk
            if pending.endswith(b"\n" if isinstance(pending, bytes) else "\n"):
                yield pending
                pending = None
            continue
        if not follow:
            break
        if idle_timeout is not None and time.monotonic() - last_data >= idle_timeout:
            break
        time.sleep(poll_interval)
    if pending:
        yield pending  # the last line of a finished file may lack its newline


def localize_stream(
    model: Any,
    lines: TextIO | Iterator[str],
    *,
    window: int | None = None,
    on_error: Callable[[int, str], Any] | None = None,
    follow: bool = False,
    idle_timeout: float | None = None,
    hmm: bool = False,
) -> Iterator[tuple[int, int]]:
    """Localize each descriptor line as it arrives.

    Parameters
    ----------
    model : fitted PlaceLocalizer
        Anything with ``predict`` (and ``n_features_in_``, ``n_places_``).
    lines : text or binary file, or iterable of str or bytes
        One descriptor per line; blank lines are ignored. Bytes are decoded as UTF-8 line by line:
        a line that is not UTF-8 is a malformed line like any other.
    window : int, optional
        Sequence-filter window a (SPEC §6); None: raw predictions.
    on_error : callable, optional
        Called as ``on_error(line_number, message)`` for each malformed line (which is skipped).
        Default: ignore.
    follow, idle_timeout
        For a file being appended to: see :func:`read_lines`.
    hmm : bool
        Decode with the online HMM over places (:class:`btel.sequence_decoding.HMMDecoder`, default
        options) on each frame's per-place scores instead of frame by frame; costs O(N·b) per frame
        for BTEL. Not combined with ``window``.

    Yields
    ------
    (line_number, place) : (int, int)
        1-based line number of the input and the (filtered) place index.
    """
    if hasattr(lines, "readline"):
        lines = read_lines(lines, follow=follow, idle_timeout=idle_timeout)  # type: ignore[arg-type]
    n_features = getattr(model, "n_features_in_", None)
    if hmm and window is not None:
        raise InvalidParameterError("choose the HMM or the sequence filter (window), not both.")
    filt = SequenceFilter(window, n_places=getattr(model, "n_places_", None)) if window is not None else None
    stream = model.stream()
    decoder = None
    if hmm:
        from .sequence_decoding import HMMDecoder, zscore_rows

        decoder = HMMDecoder(int(model.n_places_))
    for number, line in enumerate(lines, start=1):
        if isinstance(line, (bytes, bytearray)):
            try:
                line = bytes(line).decode("utf-8")
            except UnicodeDecodeError as exc:
                if on_error is not None:
                    on_error(number, f"not UTF-8 text (byte 0x{line[exc.start]:02x} at column {exc.start + 1}).")
                continue
        if not line.strip():
            continue
        if line.strip().lower() == RESET_LINE:  # a new traverse: forget the sequence state
            stream.reset()
            if filt is not None:
                filt.reset()
            if decoder is not None:
                decoder.reset()
            continue
        try:
            q = parse_descriptor_line(line, n_features)
        except InvalidDescriptorsError as exc:
            if on_error is not None:
                on_error(number, str(exc))
            continue
        try:
            if decoder is not None:
                place = decoder.update(zscore_rows(stream.place_scores(q)[None, :])[0])
            else:
                place = int(stream.search(q, 1)[1][0])
        except (InvalidDescriptorsError, DimensionMismatchError) as exc:  # a model without n_features_in_
            if on_error is not None:
                on_error(number, str(exc))
            continue
        yield number, (filt.update(place) if filt is not None else place)
