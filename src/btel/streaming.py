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

**Limits.** A line holds at most ``$BTEL_MAX_LINE_BYTES`` bytes (default 1 MiB = 1,048,576, newline
excluded; :func:`max_line_bytes`): a longer one is read through in pieces without being kept, and
reported as malformed. Values must be finite ASCII decimals whose float32 value and squared norm
are finite (:func:`parse_descriptor_line`).

**Speed.** Lines of comma-separated numbers are parsed by orjson from the raw bytes
(``benchmarks/bench_stream.py`` measures lines per second against the previous token-by-token parser).
"""

from __future__ import annotations

import os
import re
import time
from typing import Any, Callable, Iterator, TextIO

import numpy as np
import orjson

from .exceptions import DimensionMismatchError, InvalidDescriptorsError, InvalidParameterError
from .sequence import SequenceFilter
from .threads import one_blas_thread

__all__ = ["parse_descriptor_line", "read_lines", "localize_stream", "RESET_LINE", "max_line_bytes", "LineTooLong",
           "MAX_LINE_ENV", "DEFAULT_MAX_LINE_BYTES"]

#: An input line that starts a new traverse: the sequence filter, the HMM and the front end's
#: delta history forget the past (e.g. the robot was carried to another place).
RESET_LINE = "reset"

_SEPARATORS = re.compile(r"[,\s]+")
#: A finite decimal number: optional sign, digits with an optional point (or a point and digits),
#: optional exponent. ASCII only: no ``1_0``, no other scripts' digits, no hex, no nan/inf words.
_DECIMAL = re.compile(r"[+-]?(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][+-]?[0-9]+)?\Z", re.ASCII)
_NOT_FINITE = re.compile(r"[+-]?(?:nan|inf|infinity)\Z", re.IGNORECASE)
#: Bytes a line of decimal numbers may hold; anything else sends it to the strict parser.
_NUMBER_BYTES = b"0123456789+-.eE, \t\r\n"
_FLOAT32_MAX = float(np.finfo(np.float32).max)
#: Default longest input line (bytes, newline excluded): 1 MiB, room for d ≈ 50,000 values.
DEFAULT_MAX_LINE_BYTES = 1 << 20
#: Environment variable that sets the longest accepted line in bytes (default 1 MiB).
MAX_LINE_ENV = "BTEL_MAX_LINE_BYTES"


def max_line_bytes() -> int:
    """The longest input line accepted, in bytes: ``$BTEL_MAX_LINE_BYTES`` or 1 MiB.

    A longer line is never held in memory whole: it is read in pieces, dropped, and reported as
    a malformed line. Raises :class:`~btel.exceptions.InvalidParameterError` for a value that is
    not a positive integer.
    """
    raw = os.environ.get(MAX_LINE_ENV)
    if raw is None or not raw.strip():
        return DEFAULT_MAX_LINE_BYTES
    try:
        value = int(raw.strip())
    except ValueError:
        value = 0
    if value < 1:
        raise InvalidParameterError(f"{MAX_LINE_ENV} must be a positive number of bytes; got {raw[:40]!r}. "
                                    f"Unset it for the default ({DEFAULT_MAX_LINE_BYTES} bytes).")
    return value


class LineTooLong:
    """Stands for an input line longer than the limit (its text was dropped while reading)."""

    def __init__(self, limit: int) -> None:
        self.limit = limit

    def message(self) -> str:
        return (f"line longer than {self.limit} bytes (dropped unread); raise the limit with "
                f"{MAX_LINE_ENV}=BYTES if descriptors are that long.")


def parse_descriptor_line(line: str | bytes, n_features: int | None = None) -> np.ndarray:
    """One descriptor from a line of numbers separated by commas and/or whitespace.

    Every value must be a finite ASCII decimal (``-1``, ``0.25``, ``.5``, ``3e-4``) whose
    float32 value is finite, and the squared norm of the line must not overflow float32 (the
    front end's L2 normalisation computes it). Anything else — ``1_0``, digits of other scripts,
    hex, ``nan``/``inf``, ``3.5e38`` — makes the line malformed.

    A line of comma-separated JSON-style numbers is parsed by orjson (the common case: ≈ 10×
    faster than Python's ``float`` per token); any other line goes token by token through a
    strict pattern, which also names the offending value.

    Parameters
    ----------
    line : str or bytes (UTF-8)
    n_features : int, optional
        Number of values the line must hold (the model's d).

    Returns
    -------
    ndarray of shape (1, n_features), float32

    Raises
    ------
    InvalidDescriptorsError
        Empty line, a value that is not a finite decimal, a value or squared norm outside
        float32's range, or the wrong number of values.
    """
    return _parse(line, n_features, False)


def _parse(line: str | bytes, n_features: int | None, clean: bool) -> np.ndarray:
    """:func:`parse_descriptor_line`; ``clean``: the bytes are known to hold only :data:`_NUMBER_BYTES`."""
    raw = line if isinstance(line, (bytes, bytearray)) else line.encode("utf-8", "surrogatepass")
    values = None
    if clean or not raw.translate(None, _NUMBER_BYTES):  # only digits, signs, points, exponents, separators
        text = raw.strip()
        if b"," not in text:
            text = b",".join(text.split())
        try:
            parsed = orjson.loads(b"[" + text + b"]")
            values = np.array(parsed, dtype=np.float64)
        except (orjson.JSONDecodeError, ValueError, TypeError, OverflowError):
            values = None  # '+1', '.5', '5.', '01', '1,,2', ... : the strict parser decides
        if values is not None and values.ndim != 1:
            values = None
    if values is None:
        values = _parse_tokens(raw.decode("utf-8", "replace") if isinstance(line, (bytes, bytearray)) else line,
                               n_features)
    if values.size == 0:
        raise InvalidDescriptorsError("empty line (expected one descriptor).")
    if n_features is not None and values.size != n_features:
        raise InvalidDescriptorsError(f"expected {n_features} values, got {values.size}.")
    big = np.abs(values) > _FLOAT32_MAX
    if big.any():
        column = int(np.flatnonzero(big)[0])
        raise InvalidDescriptorsError(
            f"value {column + 1} is outside float32's range (|v| > 3.4e38); scale the descriptors.")
    square = float(values @ values)
    if not square <= _FLOAT32_MAX:
        raise InvalidDescriptorsError(
            f"the values are too large: their squared norm ({square:.3g}) overflows float32 (3.4e38); scale the "
            "descriptors down.")
    return values.astype(np.float32).reshape(1, -1)


def _parse_tokens(line: str, n_features: int | None) -> np.ndarray:
    """The strict token-by-token parser (every value checked against :data:`_DECIMAL`; the count first)."""
    tokens = [t for t in _SEPARATORS.split(line.strip()) if t]
    if tokens and n_features is not None and len(tokens) != n_features:
        raise InvalidDescriptorsError(f"expected {n_features} values, got {len(tokens)}.")
    for column, token in enumerate(tokens):
        if not _DECIMAL.match(token):
            if _NOT_FINITE.match(token):
                raise InvalidDescriptorsError(f"value {column + 1} is {token!r}; descriptors must be finite.")
            raise InvalidDescriptorsError(
                f"{token[:40]!r} is not a number (values are ASCII decimals such as 0.25 or -1.5e-3).")
    return np.array([float(t) for t in tokens], dtype=np.float64)


def read_lines(
    stream: TextIO,
    *,
    follow: bool = False,
    poll_interval: float = 0.1,
    idle_timeout: float | None = None,
    max_line: int | None = None,
) -> Iterator[Any]:
    """Yield complete lines from ``stream`` as they arrive (a :class:`LineTooLong` for each over-long one).

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
    max_line : int, optional
        Longest line in bytes (characters for a text stream), newline excluded; default
        :func:`max_line_bytes` (``$BTEL_MAX_LINE_BYTES`` or 1 MiB). At most this much of a line is
        held in memory: a longer one is read through and replaced by a :class:`LineTooLong`.
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
        if not follow:
            break
        if idle_timeout is not None and time.monotonic() - last_data >= idle_timeout:
            break
        time.sleep(poll_interval)
    if skipping:
        yield LineTooLong(limit)
    elif pending:
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
    source = lines
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
    # A whole file (not followed) through a model whose answer for a frame depends on that frame
    # alone: lines are parsed one by one (errors keep their line numbers) and predicted in blocks.
    blocks = (not follow and not hmm and _is_regular_file(source) and hasattr(model, "front_end_")
              and not model.front_end_.uses_sequence and not model._sequence_context())
    pending: list[tuple[int, np.ndarray]] = []

    def flush() -> Iterator[tuple[int, int]]:
        rows = np.concatenate([q for _, q in pending])
        try:
            with one_blas_thread():  # a thin product: BLAS threads spinning cost more than they give
                places = model.search(rows, 1)[1][:, 0]
        except (InvalidDescriptorsError, DimensionMismatchError):
            places = None  # find the line at fault one by one below
        for j, (number, q) in enumerate(pending):
            if places is None:
                try:
                    place = int(stream.search(q, 1)[1][0])
                except (InvalidDescriptorsError, DimensionMismatchError) as exc:
                    if on_error is not None:
                        on_error(number, str(exc))
                    continue
            else:
                place = int(places[j])
            yield number, (filt.update(place) if filt is not None else place)
        pending.clear()

    for item in _parsed(lines, n_features, on_error):
        if item is None:
            continue
        number, q = item
        if isinstance(q, str):  # RESET_LINE: a new traverse, forget the sequence state
            yield from flush() if pending else ()
            stream.reset()
            if filt is not None:
                filt.reset()
            if decoder is not None:
                decoder.reset()
            continue
        if blocks:
            pending.append((number, q))
            if len(pending) >= _BLOCK_LINES:
                yield from flush()
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
    if pending:
        yield from flush()


#: Lines predicted together when a whole file is localized (:func:`localize_stream`).
_BLOCK_LINES = 256


def _is_regular_file(source: Any) -> bool:
    try:
        return hasattr(source, "fileno") and os.path.isfile(f"/proc/self/fd/{source.fileno()}") \
            if os.path.isdir("/proc/self/fd") else bool(source.seekable())
    except (OSError, ValueError, AttributeError):
        return False


def _parsed(lines: Iterator[Any], n_features: int | None,
            on_error: Callable[[int, str], Any] | None) -> Iterator[tuple[int, Any] | None]:
    """(line number, (1, d) float32 row or RESET_LINE) per input line; None for a skipped one (reported)."""
    limit = max_line_bytes()
    for number, line in enumerate(lines, start=1):
        if isinstance(line, LineTooLong) or len(line) > limit + 1:
            if on_error is not None:
                on_error(number, (line if isinstance(line, LineTooLong) else LineTooLong(limit)).message())
            yield None
            continue
        clean = isinstance(line, (bytes, bytearray)) and not line.translate(None, _NUMBER_BYTES)
        if isinstance(line, (bytes, bytearray)) and not clean:
            try:  # only lines with other bytes than a number's need decoding (the fast parser reads bytes)
                line = bytes(line).decode("utf-8")
            except UnicodeDecodeError as exc:
                if on_error is not None:
                    on_error(number, f"not UTF-8 text (byte 0x{line[exc.start]:02x} at column {exc.start + 1}).")
                yield None
                continue
        if not line.strip():
            yield None
            continue
        if isinstance(line, str) and line.strip().lower() == RESET_LINE:
            yield number, RESET_LINE
            continue
        try:
            yield number, _parse(line, n_features, clean)
        except InvalidDescriptorsError as exc:
            if on_error is not None:
                on_error(number, str(exc))
            yield None
