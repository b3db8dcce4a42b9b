"""``btel localize``: the place of every query with a saved model, in batch or as a stream."""

from __future__ import annotations

import sys
from typing import Any

import click

from ._errors import InputError
from ._inputs import _load_matrix, declared_rows, load_model
from ._names import input_names, write_predictions
from ._outputs import check_output_suffix, refuse_existing


@click.command()
@click.argument("model_path", metavar="MODEL", type=click.Path(dir_okay=False))
@click.argument("queries", required=False, type=click.Path(dir_okay=False))
@click.option("-o", "--output", "--out", "output", type=click.Path(dir_okay=False),
              help="Predictions CSV to write (.csv or .txt; not with --stream).")
@click.option("--overwrite", is_flag=True, help="Replace an existing OUTPUT predictions file.")
@click.option("--db", type=click.Path(dir_okay=False), default=None,
              help="The map descriptors MODEL was trained on (hloc .h5[:PREFIX], or btel extract's .npy): "
                   "their image names are written beside the predicted places.")
@click.option("--sequence-filter", "window", type=int, default=None,
              help="Apply the paper's sequence filter with window a (queries must be consecutive frames).")
@click.option("--stream", is_flag=True,
              help="Read one descriptor per line (numbers separated by commas/spaces) from stdin or --input and "
                   "print one prediction per line as each arrives.")
@click.option("--binary", is_flag=True,
              help="With --stream: the input is binary float32 frames, not text: each a little-endian uint32 "
                   "count n then n little-endian float32 values (n = 0: a new traverse).")
@click.option("--input", "input_path", type=click.Path(dir_okay=False, exists=True), default=None,
              help="With --stream: read this text file instead of stdin.")
@click.option("--hmm", is_flag=True,
              help="Decode the queries as one ordered traverse with the HMM over places (forward motion; no extra "
                   "stored bytes) instead of frame by frame; online (one update per frame) with --stream. It "
                   "assumes the queries advance 0 … --hmm-speed map places a frame, and hurts when they do not.")
@click.option("--hmm-speed", type=click.IntRange(min=1), default=None, metavar="V",
              help="With --hmm: the most map places the queries advance per frame (default 2: queries at the "
                   "map's frame rate; e.g. 4 for queries taken every 2nd map frame).")
@click.option("--top-k", type=int, default=None,
              help="Batch: also write the K most likely places per query (ranked output) as columns rank_1…rank_K. "
                   "They rank each query on its own: with --hmm or --sequence-filter the prediction column is the "
                   "sequence's answer and may differ from rank_1.")
@click.option("--follow", is_flag=True, help="With --stream --input: keep reading as the file grows (like tail -f).")
@click.option("--idle-timeout", type=float, default=None,
              help="With --follow: stop after this many seconds without a new line (default: run until Ctrl-C).")
@click.option("--no-progress", is_flag=True,
              help="Batch: no progress bar (shown when the queries take more than a few seconds; in a log, a line "
                   "every 10 s).")
def localize(model_path: str, queries: str | None, output: str | None, overwrite: bool, db: str | None,
             window: int | None, stream: bool, binary: bool, input_path: str | None, hmm: bool,
             hmm_speed: int | None, top_k: int | None, follow: bool, idle_timeout: float | None,
             no_progress: bool) -> None:
    """Predict the place of every query with a saved MODEL.

    \b
    Batch:  btel localize MODEL QUERIES.npy -o predictions.csv   (query,prediction CSV; with names
            from QUERIES and --db, also query_name,prediction_name)
    Stream: producer | btel localize MODEL --stream --sequence-filter 5   (or --hmm)
            btel localize MODEL --stream --input frames.txt --follow
            camera | btel localize MODEL --stream --binary   (float32 frames, see --binary)
    In stream mode each line of input is one descriptor; each output line is the place index of the
    next well-formed input line. A malformed line (wrong count, not a number, NaN) gets a one-line
    error naming its line number on stderr, produces no output line, and the stream goes on (the command
    then exits 1: not every line was answered). Blank lines and # comments are skipped; a last line
    without its newline is reported, not answered.
    """
    batch = (queries, output, db, top_k) != (None,) * 4
    streaming = (input_path, idle_timeout) != (None, None) or follow or binary
    for broken, message in (
            (hmm and window is not None, "choose --hmm or --sequence-filter, not both."),
            (hmm_speed is not None and not hmm, "--hmm-speed sets the speed of --hmm: give --hmm too."),
            (stream and batch, "--stream reads stdin (or --input) and writes stdout; QUERIES, -o, --db and "
                               "--top-k are for batch localization."),
            (not stream and streaming, "--input, --follow, --idle-timeout and --binary need --stream."),
            (not stream and None in (queries, output),
             f"give {' and '.join(w for w, v in (('QUERIES', queries), ('-o/--output FILE', output)) if v is None)} "
             "(or use --stream)."),
            (follow and input_path is None, "--follow needs --input FILE (stdin waits for new lines anyway)."),
            (idle_timeout is not None and not follow, "--idle-timeout only applies with --follow."),
            (idle_timeout is not None and not 0 < idle_timeout < 1e9,  # nan and inf included: they never end
             f"--idle-timeout must be a number of seconds above 0 and below 10⁹ (about 30 years); got {idle_timeout}. "
             "Leave it out to run until Ctrl-C.")):
        if broken:
            raise click.UsageError(message)
    _check_window(window)
    hmm_options = {} if hmm_speed is None else {"vmax": hmm_speed}
    if stream:
        return _localize_stream(load_model(model_path), input_path, follow, idle_timeout, window, hmm, binary,
                                hmm_options)
    check_output_suffix(output, "-o", "a predictions CSV", (".csv", ".txt"))
    refuse_existing(output, "-o", overwrite, {"MODEL": model_path, "QUERIES": queries, "--db": db})
    model = load_model(model_path)
    if top_k is not None:  # before the answers it sizes are weighed
        _check_top_k(top_k, model.n_places_, model_path)
    declared = declared_rows(queries)
    if declared is not None:  # before the file is read (reading checks every value)
        _check_answers_fit(declared, top_k, queries)
    Q = _load_matrix(queries, "query descriptors", mmap=True)  # a float32 .npy is read as it is used
    if Q.shape[1] != model.n_features_in_:  # the library would name its variable (Q), not the file
        raise InputError(f"queries {queries} have {Q.shape[1]} values per row, but MODEL was fitted on "
                         f"{model.n_features_in_}-value descriptors; extract the queries with the same "
                         "descriptor (and settings) as the map.")
    _check_answers_fit(Q.shape[0], top_k, queries)
    q_names, db_names = input_names(db, queries, model.n_places_, Q.shape[0])
    if db is not None and db_names is None:
        from ..datasets.row_names import row_names

        recorded = row_names(db)
        why = ("records no image names (a .npy names its images only with btel extract's PATH.json beside it)"
               if recorded is None else f"names {len(recorded)} images, but MODEL has {model.n_places_} places")
        raise InputError(f"--db {db} {why}; --db is there to name the predicted places: give the map MODEL was "
                         "trained on as an hloc .h5, or as btel extract's .npy with its .json.")
    # A frame-by-frame model answers row blocks of the queries as it answers them all: the memory of a
    # query file larger than RAM's share is a block's, not the file's.
    by_frame = not hmm and not model.front_end_.uses_sequence and not model._sequence_context()
    predictions = (model.predict_sequence(Q, "hmm", **hmm_options) if hmm else
                   _in_row_blocks(model.predict, Q, None if no_progress else "localizing") if by_frame
                   else model.predict(Q))
    if window is not None:
        from ..sequence.filter import filter_sequence

        predictions = filter_sequence(predictions, window, n_places=model.n_places_)
    ranked = (None if top_k is None else
              _in_row_blocks(lambda B: model.rank(B, top_k), Q, None if no_progress else "ranking") if by_frame
              else model.rank(Q, top_k))
    write_predictions(output, predictions, ranked, q_names, db_names, overwrite=overwrite)
    named = {(True, True): " with query and map image names", (True, False): " with query image names",
             (False, True): " with map image names", (False, False): ""}[bool(q_names), bool(db_names)]
    hint = " (give --db MAP to name the predicted places too)" if q_names and db is None else ""
    click.echo(f"{len(predictions)} predictions{named} written to {output}{hint}")


#: Bytes of queries answered at once in batch mode (a memory-mapped query file is read block by block).
_QUERY_BLOCK_BYTES = 64 << 20


#: Queries answered first to time a batch (more than the methods' single-query paths take, so the probe
#: runs as the batch does); a batch whose rest would take longer than _QUIET_SECONDS is answered in blocks
#: of about _BLOCK_SECONDS, at least _MIN_BLOCK_ROWS (a block rescans the map), under a progress bar.
_PROBE_ROWS, _QUIET_SECONDS, _BLOCK_SECONDS, _MIN_BLOCK_ROWS = 64, 3.0, 1.0, 256


def _in_row_blocks(answer: Any, Q: Any, progress: str | None = None) -> Any:
    """``answer(Q)`` computed on row blocks of ``Q`` of at most :data:`_QUERY_BLOCK_BYTES` and stacked.

    With ``progress`` (the bar's label), the first :data:`_PROBE_ROWS` rows are timed: when the rest would
    take longer than :data:`_QUIET_SECONDS`, blocks of about :data:`_BLOCK_SECONDS` (at least
    :data:`_MIN_BLOCK_ROWS` rows) each advance a bar on a terminal (a line every 10 s in a log), so a slow
    method's minutes of queries are not silent.
    """
    import time

    import numpy as np

    rows = max(1, _QUERY_BLOCK_BYTES // max(1, 4 * Q.shape[1]))
    n = Q.shape[0]
    if progress is None or n <= 2 * _PROBE_ROWS:
        if n <= rows:
            return answer(Q)
        return np.concatenate([answer(np.ascontiguousarray(Q[a:a + rows])) for a in range(0, n, rows)])
    start = time.perf_counter()
    parts = [answer(np.ascontiguousarray(Q[:_PROBE_ROWS]))]
    per_row = (time.perf_counter() - start) / _PROBE_ROWS
    bar = None
    if per_row * (n - _PROBE_ROWS) > _QUIET_SECONDS:
        from ..core.progress import progress_bar

        rows = max(1, min(rows, max(_MIN_BLOCK_ROWS, int(_BLOCK_SECONDS / max(per_row, 1e-9)))))
        bar = progress_bar(n, progress, "query", True)
        bar.update(_PROBE_ROWS)
    try:
        for a in range(_PROBE_ROWS, n, rows):
            parts.append(answer(np.ascontiguousarray(Q[a:a + rows])))
            if bar is not None:
                bar.update(min(rows, n - a))
    finally:
        if bar is not None:
            bar.close()
    return np.concatenate(parts)


def _check_answers_fit(n_queries: int, top_k: int | None, queries: str) -> None:
    """The answers are held whole (an (n, 1 + K) int64 table) until the CSV is written: refused, before any
    query is answered, when that table needs more than the machine's memory."""
    from ..core.limits import check_fits_machine

    check_fits_machine(8.0 * n_queries * (1 + (top_k or 0)), f"the answers to the {n_queries:,} queries of {queries}",
                       "split the queries into several files.")


def _check_top_k(top_k: int | None, n_places: int, model_path: str) -> None:
    """``--top-k``, refused in the flag's words when it is not 1 … the map's N places (a ranking of more
    places than the map has would be cut to N columns without a word, as ``btel evaluate --k`` refuses)."""
    if top_k is not None and not 1 <= top_k <= n_places:
        raise click.UsageError(f"--top-k {top_k}: a ranking holds 1 to the map's N = {n_places} places (MODEL "
                               f"{model_path}); give --top-k between 1 and {n_places}.")


def _check_window(window: int | None) -> None:
    """``--sequence-filter``, refused in the flag's words (the library names its parameter, window)."""
    if window is None:
        return
    from ..sequence.filter import MAX_WINDOW

    if window < 1:
        raise click.UsageError(f"--sequence-filter must be an integer ≥ 1 (the window in places); got {window}.")
    if window > MAX_WINDOW:
        raise click.UsageError(f"--sequence-filter must be at most {MAX_WINDOW} places; got {window}.")


def _localize_stream(model: Any, input_path: str | None, follow: bool, idle_timeout: float | None,
                     window: int | None, hmm: bool = False, binary: bool = False,
                     hmm_options: dict[str, Any] | None = None) -> None:
    """The --stream loop: one output line per well-formed input line, flushed before more input is awaited."""
    from ..sequence.streaming import localize_stream

    n_bad = n_out = 0
    unit = "frame" if binary else "line"

    def report(line_number: int, message: str) -> None:
        nonlocal n_bad
        n_bad += 1
        click.echo(f"error: {unit} {line_number}: {message} (skipped)", err=True)

    def warn(line_number: int, message: str) -> None:
        click.echo(f"warning: {unit} {line_number}: {message}", err=True)

    if input_path is None and sys.stdin is None:
        raise InputError("standard input is closed: pipe the descriptors in, or give --input FILE.")
    if sys.stdout is None:
        raise InputError("standard output is closed: the answers need somewhere to go (a file or a pipe).")
    out = sys.stdout

    def write(text: str | None) -> None:
        try:
            out.write(text) if text is not None else out.flush()
        except BrokenPipeError:
            raise  # the reader went away: the command ends quietly (btel.cli)
        except OSError as exc:
            raise click.ClickException(
                f"cannot write the answers to standard output: {exc.strerror or exc}; free the space or send "
                "the output elsewhere.") from exc

    # Bytes, decoded line by line in localize_stream: a byte that is not UTF-8 is one malformed line,
    # not the end of the stream (a text stream's decoder would raise and stop it).
    source = open(input_path, "rb") if input_path is not None else getattr(sys.stdin, "buffer", sys.stdin)
    try:
        for _, place in localize_stream(model, source, window=window, on_error=report, follow=follow, hmm=hmm,
                                        hmm_options=hmm_options, idle_timeout=idle_timeout, binary=binary,
                                        on_flush=lambda: write(None), on_warning=warn):
            write(f"{place}\n")  # flushed by on_flush: a reader of the pipe sees each answer at once
            n_out += 1
    finally:  # Ctrl-C, the usual end of a --follow stream, still says what was skipped (then exits 130)
        if input_path is not None:
            source.close()
        if n_bad:
            click.echo(f"{n_out} predictions; {n_bad} malformed {unit}(s) skipped", err=True)
    if n_bad:  # as a run with a row not measured (docs/decisions/cli-exit-codes.md): not every input answered
        from ._errors import EXIT_SOME_ROWS_FAILED

        raise click.exceptions.Exit(EXIT_SOME_ROWS_FAILED)
