"""Descriptor lines: one descriptor per text line, values separated by commas and/or whitespace.

A value is a finite ASCII decimal (``-1``, ``0.25``, ``.5``, ``3e-4``) whose float32 value is
finite, and the squared norm of a line must not overflow float32 (the front end's L2 normalisation
computes it). Anything else — ``1_0``, digits of other scripts, hex, ``nan``/``inf``, ``3.5e38``,
an empty value (``1,,2``, a leading or trailing comma), the wrong number of values — makes the line malformed (:class:`~btel.exceptions.InvalidDescriptorsError`
naming the value).

**Fast path.** A line of JSON numbers separated by one kind of separator — commas
(``numpy.savetxt(..., delimiter=",")``) or single spaces or tabs (``numpy.savetxt``'s default) —
is read by orjson from the raw bytes, spaces turned into commas; a block of such lines becomes one
array with one vectorised range check (:func:`parse_lines`). A line holding none of the bytes of
JSON's other values (``u`` and ``l`` of ``true``/``false``/``null``, quotes, brackets) parses as
JSON only if it is such numbers, so no value can slip through as something else. Any other line
(``+1``, ``5.``, mixed separators, repeated whitespace, a bad value) goes through the strict parser, token by
token, which also names the offending value.

**Limits.** A line holds at most ``$BTEL_MAX_LINE_BYTES`` bytes (default 1 MiB, newline excluded;
:func:`max_line_bytes`); the reader drops a longer one unread (:class:`LineTooLong`).
"""

from __future__ import annotations

import itertools
import os
import re
from typing import Sequence

import numpy as np
import orjson

from ..exceptions import InvalidDescriptorsError, InvalidParameterError

__all__ = ["parse_descriptor_line", "parse_lines", "parse_strict", "max_line_bytes", "LineTooLong",
           "MAX_LINE_ENV", "DEFAULT_MAX_LINE_BYTES"]

_SEPARATORS = re.compile(r"[,\s]+")
#: A finite decimal number: optional sign, digits with an optional point (or a point and digits),
#: optional exponent. ASCII only: no ``1_0``, no other scripts' digits, no hex, no nan/inf words.
#: Each character has one way to match (the fraction's digits only after a point): ``[0-9]+\.?[0-9]*``
#: split a run of digits in every possible way, quadratic backtracking on ``1111…1x`` (a 1 MiB line hung).
_DECIMAL = re.compile(r"[+-]?(?:[0-9]+(?:\.[0-9]*)?|\.[0-9]+)(?:[eE][+-]?[0-9]+)?\Z", re.ASCII)
#: An empty field: a comma at the start, or at the end, or followed by another with only whitespace between.
_EMPTY_FIELD = re.compile(r"^\s*,|,\s*,|,\s*$")
_NOT_FINITE = re.compile(r"[+-]?(?:nan|inf|infinity)\Z", re.IGNORECASE)
#: A byte of each JSON value that is not a number (true/false/null, strings, arrays, objects): a line
#: holding one goes to the strict parser (memchr scans: far cheaper than checking every byte).
_NOT_NUMBERS = (b"u", b"l", b'"', b"[", b"{")
_FLOAT32_MAX = float(np.finfo(np.float32).max)
#: Default longest input line (bytes, newline excluded): 1 MiB, room for d ≈ 50,000 values.
DEFAULT_MAX_LINE_BYTES = 1 << 20
#: The largest value it may take (1 GiB: a line of some 40 million values; one line is held in memory whole).
LARGEST_LINE_BYTES = 1 << 30
#: Environment variable that sets the longest accepted line in bytes (default 1 MiB).
MAX_LINE_ENV = "BTEL_MAX_LINE_BYTES"


def max_line_bytes() -> int:
    """The longest input line accepted, in bytes: ``$BTEL_MAX_LINE_BYTES`` or 1 MiB.

    Raises :class:`~btel.exceptions.InvalidParameterError` for a value that is not an integer from 1 to
    :data:`LARGEST_LINE_BYTES`.
    """
    raw = os.environ.get(MAX_LINE_ENV)
    if raw is None or not raw.strip():
        return DEFAULT_MAX_LINE_BYTES
    try:
        value = int(raw.strip())
    except ValueError:
        value = 0
    if not 1 <= value <= LARGEST_LINE_BYTES:
        raise InvalidParameterError(f"{MAX_LINE_ENV} must be a number of bytes from 1 to {LARGEST_LINE_BYTES} (1 GiB); "
                                    f"got {raw[:40]!r}. Unset it for the default ({DEFAULT_MAX_LINE_BYTES} bytes).")
    return value


class LineTooLong:
    """Stands for an input line longer than the limit (its text was dropped while reading)."""

    def __init__(self, limit: int) -> None:
        self.limit = limit

    def message(self) -> str:
        return (f"line longer than {self.limit} bytes (dropped unread); raise the limit with "
                f"{MAX_LINE_ENV}=BYTES if descriptors are that long.")


def parse_descriptor_line(line: str | bytes, n_features: int | None = None) -> np.ndarray:
    """One descriptor from a line of numbers separated by commas and/or whitespace (module docstring).

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
    raw = line if isinstance(line, (bytes, bytearray)) else line.encode("utf-8", "surrogatepass")
    rows, fast = parse_lines([bytes(raw)], n_features)
    return rows if fast[0] else parse_strict(line, n_features)


def parse_lines(lines: Sequence[bytes], n_features: int | None) -> tuple[np.ndarray, list[bool]]:
    """The fast path over a block of lines: ``(rows, fast)``.

    ``rows`` (float32, one row per True in ``fast``, in order) holds the lines that the fast path
    read and that are valid descriptors; a line with ``fast[i]`` False needs :func:`parse_strict`,
    which returns its row or raises the error naming what is wrong with it.
    """
    loads = orjson.loads
    parsed: list[list[float]] = []
    fast = [False] * len(lines)
    width = n_features
    for i, raw in enumerate(lines):
        if b"u" in raw or b"l" in raw or b'"' in raw or b"[" in raw or b"{" in raw:  # _NOT_NUMBERS
            continue
        if b"," not in raw:
            raw = raw.replace(b" ", b",").replace(b"\t", b",")
        try:
            values = loads(b"[" + raw + b"]")
        except orjson.JSONDecodeError:  # '+1', '.5', '5.', '01', '1,,2', '1  2', a 20-digit integer ...
            continue
        if not values or (width is not None and len(values) != width):
            continue
        width = len(values)
        parsed.append(values)
        fast[i] = True
    if not parsed:
        return np.empty((0, width or 0), dtype=np.float32), fast
    # One flat pass over the floats (every row has the block's width): np.array would first discover
    # the nested lists' shape, which costs more (streaming decision page).
    values64 = np.fromiter(itertools.chain.from_iterable(parsed), dtype=np.float64,
                           count=len(parsed) * width).reshape(len(parsed), width)
    # Out of float32's range, or a squared norm that overflows it: the strict parser names it.
    squares = np.einsum("ij,ij->i", values64, values64)
    bad = ~(np.abs(values64).max(axis=1) <= _FLOAT32_MAX) | ~(squares <= _FLOAT32_MAX)
    if bad.any():
        rows = np.flatnonzero(fast)
        for j in np.flatnonzero(bad):
            fast[rows[j]] = False
        values64 = values64[~bad]
    return values64.astype(np.float32), fast


def _count_hint(line: str, tokens: list[str]) -> str:
    """Why a line may hold the wrong number of values: a token that is not a number (another
    separator such as ``;``, a NUL byte), or carriage returns ending lines instead of newlines."""
    if "\r" in line.strip():
        return (" (the line holds carriage returns inside it: lines must end with a newline, \\n or \\r\\n, "
                "not a bare \\r)")
    bad = next((t for t in tokens if not _DECIMAL.match(t)), None)
    if bad is None:
        if len(tokens) == 1:  # np.savetxt of one 1-D descriptor writes one value per line
            return (" (a line holds one whole descriptor: np.savetxt(f, Q) of a 2-D Q writes one per line; for a "
                    "single descriptor q write q[None])")
        return ""
    return (f"; {bad[:40]!r} is not a number (values are ASCII decimals separated by commas or "
            "whitespace)")


def parse_strict(line: str | bytes, n_features: int | None) -> np.ndarray:
    """One line through the strict parser: its (1, d) float32 row, or the error naming what is wrong."""
    if isinstance(line, (bytes, bytearray)):
        line = line.decode("utf-8", "replace")
    tokens = [t for t in _SEPARATORS.split(line.strip()) if t]
    if not tokens:
        raise InvalidDescriptorsError("empty line (expected one descriptor).")
    # A comma with no value before it (",,", a leading or trailing comma) is a missing value, not a separator
    # to skip: skipped, a line missing one value and holding one extra would pass for a whole row.
    empty = _EMPTY_FIELD.search(line.strip())
    if empty is not None:
        column = 1 + sum(1 for t in _SEPARATORS.split(line.strip()[:empty.start() + 1]) if t)
        raise InvalidDescriptorsError(f"value {column} is empty (two commas with nothing between them, or a comma "
                                      "at the start or end of the line); write every value of the descriptor.")
    if n_features is not None and len(tokens) != n_features:
        raise InvalidDescriptorsError(f"expected {n_features} values, got {len(tokens)}{_count_hint(line, tokens)}.")
    for column, token in enumerate(tokens):
        if not _DECIMAL.match(token):
            if _NOT_FINITE.match(token):
                raise InvalidDescriptorsError(f"value {column + 1} is {token!r}; descriptors must be finite.")
            raise InvalidDescriptorsError(
                f"{token[:40]!r} is not a number (values are ASCII decimals such as 0.25 or -1.5e-3).")
    values = np.array([float(t) for t in tokens], dtype=np.float64)
    big = np.abs(values) > _FLOAT32_MAX
    if big.any():
        column = int(np.flatnonzero(big)[0])
        raise InvalidDescriptorsError(
            f"value {column + 1} is outside float32's range (|v| > 3.4e38); scale the descriptors.")
    square = float(values @ values)
    if not square <= _FLOAT32_MAX:
        raise InvalidDescriptorsError(f"the values are too large: their squared norm ({square:.3g}) "
                                      "overflows float32 (3.4e38); scale the descriptors down.")
    return values.astype(np.float32).reshape(1, -1)
