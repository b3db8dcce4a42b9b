"""Streaming localization: descriptors arrive one per text line (or binary frame), places leave one per line.

This is what a robot runs: a camera pipeline writes each frame's global descriptor as a line of
numbers (separated by commas and/or whitespace, as ``numpy.savetxt`` writes them) to a pipe or an
append-only file, and every line is localized as soon as it is complete, with the paper's sequence
filter applied across the stream. The model's front end runs online too
(:class:`btel.sequence.querystream.QueryStream`): with delta descriptors it keeps the last 2w frames and
answers from the first frame on. A line ``reset`` starts a new traverse: the filter, the HMM and
the delta history forget the past. A malformed line — a wrong number of values, something that is
not a number, NaN or infinity — is reported with its line number and skipped; it does not stop the
stream and does not enter the filter's history. So is a last line without its newline (the producer
may have stopped in the middle of it). Blank lines and ``#`` comments are skipped, a UTF-8 byte-order
mark is dropped, and an all-zero line (a blank frame) is answered with a warning naming its line. Lines are parsed by :mod:`btel.sequence.lineparse`; binary
float32 frames (``binary=True``) are read by :func:`btel.sequence.streamread.read_frames`, whose docstring
states the frame format.

>>> import io
>>> for line_number, place in localize_stream(model, io.StringIO("0.1,0.2,...\\n")):  # doctest: +SKIP
...     print(place)

**Blocks.** When a model answers each frame from that frame alone (no delta front end, no sequence
method, no HMM), the lines that are already waiting — a whole file, or what a pipe holds — are
parsed and predicted together, up to 256 at a time; a line that arrives alone is answered alone,
before the next read waits (:func:`btel.sequence.streamread.chunk_lines`). The answers equal those of one
line at a time (``benchmarks/bench_stream.py`` measures lines per second for each format).

``btel localize MODEL --stream [--input FILE [--follow]] [--binary] [--sequence-filter A]`` is the
command-line front end.
"""

from __future__ import annotations

import contextlib
import os
import warnings
from typing import Any, Callable, Iterator, TextIO

import numpy as np

from ..exceptions import DimensionMismatchError, InvalidDescriptorsError, InvalidParameterError
from .lineparse import (DEFAULT_MAX_LINE_BYTES, MAX_LINE_ENV, LineTooLong, max_line_bytes,
                        parse_descriptor_line, parse_lines, parse_strict)
from .filter import SequenceFilter
from .streamread import IDLE, BadFrame, CutLine, chunk_lines, is_pipe, read_frames, read_lines
from ..core.rows import BlankQueryWarning
from ..core.threads import one_blas_thread

__all__ = ["parse_descriptor_line", "read_lines", "localize_stream", "RESET_LINE", "max_line_bytes",
           "LineTooLong", "MAX_LINE_ENV", "DEFAULT_MAX_LINE_BYTES"]

#: An input line that starts a new traverse: the sequence filter, the HMM and the front end's
#: delta history forget the past (e.g. the robot was carried to another place).
RESET_LINE = "reset"
#: What the first bytes of a line may hold besides its values: a UTF-8 byte-order mark (a file
#: saved by a Windows tool); it is dropped.
_BOM = b"\xef\xbb\xbf"
#: Lines parsed and predicted together at most (:func:`localize_stream`).
_BLOCK_LINES = 256


def localize_stream(
    model: Any,
    lines: TextIO | Iterator[str],
    *,
    window: int | None = None,
    on_error: Callable[[int, str], Any] | None = None,
    follow: bool = False,
    idle_timeout: float | None = None,
    hmm: bool = False,
    binary: bool = False,
    on_flush: Callable[[], Any] | None = None,
    hmm_options: dict[str, Any] | None = None,
    on_warning: Callable[[int, str], Any] | None = None,
) -> Iterator[tuple[int, int]]:
    """Localize each descriptor line as it arrives.

    Parameters
    ----------
    model : fitted PlaceLocalizer
        Anything with ``predict`` (and ``n_features_in_``, ``n_places_``).
    lines : text or binary file, or iterable of str or bytes
        One descriptor per line; blank lines and comment lines (starting with ``#``, as
        ``numpy.savetxt(header=...)`` writes them) are ignored, and a UTF-8 byte-order mark at the
        start of a line is dropped. Bytes are decoded as UTF-8 line by line: a line that is not
        UTF-8 is a malformed line like any other. From a file or stream only whole lines are
        answered: a last line without its newline (the producer may have stopped in the middle of
        it) is reported through ``on_error``, not answered.
    window : int, optional
        Sequence-filter window a (the paper's notation); None: raw predictions.
    on_error : callable, optional
        Called as ``on_error(number, message)`` for each malformed line or frame (which is skipped).
        Default: ignore.
    follow, idle_timeout
        For a file being appended to: see :func:`btel.sequence.streamread.read_lines`.
    hmm : bool
        Decode with the online HMM over places (:class:`btel.sequence.hmm.HMMDecoder`, default
        options) on each frame's per-place scores instead of frame by frame; costs O(N·b) per frame
        for BTEL. Not combined with ``window``.
    hmm_options : dict, optional
        Options of that decoder (e.g. ``{"vmax": 4}``: queries advance up to 4 map places a frame;
        the default, 2, suits queries taken at the map's frame rate).
    binary : bool
        ``lines`` is a binary stream of float32 frames (:func:`btel.sequence.streamread.read_frames`), not text.
    on_warning : callable, optional
        Called as ``on_warning(number, message)`` for each line or frame that is answered but
        carries nothing to localize by (all zeros: a blank or covered frame). Default: one
        :class:`~btel.core.rows.BlankQueryWarning` for the first such line of the stream.
    on_flush : callable, optional
        Called after the last answer of each block (and after each answer given alone): where a
        writer flushes its output, so that a reader of a pipe sees every answer before the next
        input is awaited.

    Yields
    ------
    (number, place) : (int, int)
        1-based line (or frame) number of the input and the (filtered) place index.
    """
    if hmm and window is not None:
        raise InvalidParameterError("choose the HMM or the sequence filter (window), not both.")
    source = lines
    n_features = getattr(model, "n_features_in_", None)
    if binary:
        items: Any = read_frames(source, int(n_features),  # type: ignore[arg-type]
                                 follow=follow, idle_timeout=idle_timeout)
    elif hasattr(source, "readline"):
        chunked = not follow and not hasattr(source, "encoding") and hasattr(source, "read")
        items = chunk_lines(source) if chunked else read_lines(source, follow=follow,
                                                               idle_timeout=idle_timeout)
    else:
        items = iter(source)
    filt = SequenceFilter(window, n_places=getattr(model, "n_places_", None)) if window is not None else None
    stream = model.stream()
    decoder = None
    if hmm:
        from .hmm import HMMDecoder

        decoder = HMMDecoder(int(model.n_places_), **(hmm_options or {}))
    # Lines that are already waiting (a whole file, a pipe's backlog) go through in blocks when a frame's
    # answer depends on that frame alone; otherwise one at a time.
    frame_by_frame = (not hmm and hasattr(model, "front_end_") and not model.front_end_.uses_sequence
                      and not model._sequence_context())
    blocks = frame_by_frame and not follow and (binary or _is_regular_file(source) or is_pipe(source))
    flush = on_flush or (lambda: None)
    blank = on_warning or _WarnOnce()
    pending: list[tuple[int, Any]] = []

    def answer_pending() -> Iterator[tuple[int, int]]:
        if pending:
            yield from _answer_block(model, stream, filt, _rows(pending, n_features, on_error), on_error, blank)
            pending.clear()
            flush()

    number = 0
    try:
        for item in items:
            if item is IDLE:
                yield from answer_pending()
                continue
            number += 1
            if number == 1 and not binary:
                _refuse_a_file_format(item)
            if blocks:
                pending.append((number, item))
                if len(pending) >= _BLOCK_LINES:
                    yield from answer_pending()
                continue
            for row in _rows([(number, item)], n_features, on_error):
                answer = _answer_one(stream, filt, decoder, row, on_error, blank)
                if answer is not None:
                    yield answer
                    flush()
    except InvalidDescriptorsError:  # the input broke (a binary frame cut short): answer what came before
        yield from answer_pending()
        raise
    yield from answer_pending()


#: The first bytes of files a user may pipe in by mistake, and what each is.
_FILE_MAGIC = {b"\x93NUMPY": "a .npy file", b"PK\x03\x04": "a zip archive (.npz: descriptors or a btel model)",
               b"\x89HDF\r\n": "an HDF5 file (.h5)"}


def _refuse_a_file_format(first: Any) -> None:
    """Stop a text stream whose first line is the start of a binary file (a .npy piped in): every "line"
    would be reported as malformed, thousands of them, and nothing answered."""
    head = first.encode("latin-1", "replace") if isinstance(first, str) else first
    if not isinstance(head, (bytes, bytearray)):
        return
    what = next((name for magic, name in _FILE_MAGIC.items() if head.startswith(magic)), None)
    if what is not None:
        raise InvalidDescriptorsError(
            f"the input is {what}, not lines of text: localize a file of descriptors with "
            "`btel localize MODEL QUERIES -o predictions.csv`; a stream takes one descriptor per text line, "
            "or float32 frames with --binary.")


class _WarnOnce:
    """The default ``on_warning``: one BlankQueryWarning, naming the first blank line of the stream
    (one per line would fill the warnings registry of a long stream from a covered camera)."""

    def __init__(self) -> None:
        self.warned = False

    def __call__(self, number: int, message: str) -> None:
        if not self.warned:
            self.warned = True
            warnings.warn(f"line {number}: {message} (later blank lines of this stream are not warned about; "
                          "pass on_warning to hear of each)", BlankQueryWarning, stacklevel=4)


_BLANK = "all zeros (a blank frame?): answered, but a descriptor with no content gives no localization."


@contextlib.contextmanager
def _quiet_blanks(any_blank: bool) -> Iterator[None]:
    """Silence the model's own warning about blank rows (it numbers rows within a block, not lines
    of the stream: the stream reports them itself, by line number, once answered)."""
    if not any_blank:
        yield
        return
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", BlankQueryWarning)
        yield


def _answer_one(stream: Any, filt: SequenceFilter | None, decoder: Any, row: tuple[int, Any],
                on_error: Callable[[int, str], Any] | None,
                on_warning: Callable[[int, str], Any]) -> tuple[int, int] | None:
    """The (number, place) of one parsed row through the query stream (None for a reset or a refused row)."""
    number, q = row
    if isinstance(q, str):  # RESET_LINE: a new traverse, forget the sequence state
        stream.reset()
        for state in (filt, decoder):
            if state is not None:
                state.reset()
        return None
    blank = isinstance(q, np.ndarray) and not q.any()
    try:
        with _quiet_blanks(blank):
            if decoder is not None:
                from .hmm import zscore_rows

                place = decoder.update(zscore_rows(stream.place_scores(q)[None, :])[0])
            else:
                place = int(stream.search(q, 1)[1][0])
    except (InvalidDescriptorsError, DimensionMismatchError) as exc:  # a model without n_features_in_
        if on_error is not None:
            on_error(number, str(exc))
        return None
    if blank:
        on_warning(number, _BLANK)
    return number, (filt.update(place) if filt is not None else place)


def _answer_block(model: Any, stream: Any, filt: SequenceFilter | None, rows: list[tuple[int, Any]],
                  on_error: Callable[[int, str], Any] | None,
                  on_warning: Callable[[int, str], Any]) -> Iterator[tuple[int, int]]:
    """Answers of a block of parsed rows of a frame-by-frame model: one prediction for all, in input order."""
    numbered = [(number, q) for number, q in rows if not isinstance(q, str)]
    places = None
    if numbered:
        Q = np.concatenate([q for _, q in numbered])
        blanks = [numbered[i][0] for i in np.flatnonzero(~Q.any(axis=1))]
        try:
            with one_blas_thread(), _quiet_blanks(bool(blanks)):
                places = model.search(Q, 1)[1][:, 0].tolist()  # one BLAS thread: a thin product
        except (InvalidDescriptorsError, DimensionMismatchError):
            places = None  # find the row at fault one by one below
        for number in blanks if places is not None else ():
            on_warning(number, _BLANK)
    j = 0
    for number, q in rows:
        if isinstance(q, str) or places is None:
            answer = _answer_one(stream, filt, None, (number, q), on_error, on_warning)
            if answer is not None:
                yield answer
            continue
        place = places[j]
        j += 1
        yield number, (filt.update(place) if filt is not None else place)


def _is_regular_file(source: Any) -> bool:
    try:
        return hasattr(source, "fileno") and os.path.isfile(f"/proc/self/fd/{source.fileno()}") \
            if os.path.isdir("/proc/self/fd") else bool(source.seekable())
    except (OSError, ValueError, AttributeError):
        return False


def _rows(block: list[tuple[int, Any]], n_features: int | None,
          on_error: Callable[[int, str], Any] | None) -> list[tuple[int, Any]]:
    """(number, (1, d) float32 row or RESET_LINE) of each usable line or frame of a block, in order.

    Lines on the fast path are parsed together (:func:`btel.sequence.lineparse.parse_lines`); the others
    (blank, ``reset``, not UTF-8, or for the strict parser) one by one. Every malformed line or frame
    is reported through ``on_error`` and left out.
    """
    limit = max_line_bytes()
    out: list[tuple[int, Any] | None] = [None] * len(block)
    # Problems are reported in line order once the block is read: a line refused while reading (cut short,
    # too long) must not be reported before an earlier line that the parser refuses.
    problems: list[tuple[int, Any]] = []
    raws: list[bytes] = []
    where: list[int] = []
    for k, (number, item) in enumerate(block):
        if isinstance(item, np.ndarray) or item == RESET_LINE:  # a binary frame, or a frame count of 0
            out[k] = (number, item)
        elif isinstance(item, (LineTooLong, BadFrame, CutLine)):
            problems.append((number, item))
        elif len(item) > limit + 1:
            problems.append((number, LineTooLong(limit)))
        else:
            raw = item.encode("utf-8", "surrogatepass") if isinstance(item, str) else bytes(item)
            if raw.startswith(_BOM):
                raw = raw[len(_BOM):]
            if b"\0" in raw:  # a float32 frame holds NUL bytes in its count; text never does
                column = raw.index(b"\0") + 1
                problems.append((number, f"binary data, not a line of text (a NUL byte at column {column}); "
                                         "float32 frames are read with --binary."))
                continue
            raws.append(raw)
            where.append(k)
    parsed, fast = parse_lines(raws, n_features)
    first = 0
    for raw, k, ok in zip(raws, where, fast):
        number, item = block[k]
        if ok:
            out[k] = (number, parsed[first:first + 1])
            first += 1
            continue
        if isinstance(item, (bytes, bytearray)):
            try:  # only lines the fast path refused need decoding
                item = raw.decode("utf-8")
            except UnicodeDecodeError as exc:
                problems.append((number, f"not UTF-8 text (byte 0x{raw[exc.start]:02x} at column {exc.start + 1})."))
                continue
        text = item.strip().removeprefix("\ufeff").strip()
        if not text or text.startswith("#"):  # blank, or a comment (numpy.savetxt's header= and footer=)
            continue
        if text.lower() == RESET_LINE:
            out[k] = (number, RESET_LINE)
            continue
        try:
            out[k] = (number, parse_strict(text, n_features))
        except InvalidDescriptorsError as exc:
            problems.append((number, str(exc)))
    for number, what in sorted(problems, key=lambda problem: problem[0]):
        _report(on_error, number, what)
    return [o for o in out if o is not None]


def _report(on_error: Callable[[int, str], Any] | None, number: int, what: Any) -> None:
    if on_error is not None:
        on_error(number, what if isinstance(what, str) else what.message())
