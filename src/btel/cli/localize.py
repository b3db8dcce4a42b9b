"""``btel localize``: the place of every query with a saved model, in batch or as a stream."""

from __future__ import annotations

import csv
import sys
from pathlib import Path
from typing import Any

import click

from ._inputs import _load_matrix
from ._outputs import refuse_existing


@click.command()
@click.argument("model_path", metavar="MODEL", type=click.Path(dir_okay=False))
@click.argument("queries", required=False, type=click.Path(dir_okay=False))
@click.option("-o", "--output", type=click.Path(dir_okay=False), help="Predictions CSV to write (not with --stream).")
@click.option("--overwrite", is_flag=True, help="Replace an existing OUTPUT predictions file.")
@click.option("--sequence-filter", "window", type=int, default=None,
              help="Apply the paper's sequence filter with window a (queries must be consecutive frames).")
@click.option("--stream", is_flag=True,
              help="Read one descriptor per line (numbers separated by commas/spaces) from stdin or --input and "
                   "print one prediction per line as each arrives.")
@click.option("--binary", is_flag=True,
              help="With --stream: the input is binary float32 frames, not text: each a little-endian uint32 "
                   "count n then n little-endian float32 values (n = 0: a new traverse).")
@click.option("--input", "input_path", type=click.Path(dir_okay=False), default=None,
              help="With --stream: read this text file instead of stdin.")
@click.option("--hmm", is_flag=True,
              help="Decode the queries as one ordered traverse with the HMM over places (forward motion; no extra "
                   "stored bytes) instead of frame by frame; online (one update per frame) with --stream.")
@click.option("--top-k", type=int, default=None,
              help="Batch: also write the K most likely places per query (ranked output) as columns rank_1…rank_K.")
@click.option("--follow", is_flag=True, help="With --stream --input: keep reading as the file grows (like tail -f).")
@click.option("--idle-timeout", type=float, default=None,
              help="With --follow: stop after this many seconds without a new line (default: run until Ctrl-C).")
def localize(model_path: str, queries: str | None, output: str | None, overwrite: bool, window: int | None,
             stream: bool, binary: bool, input_path: str | None, hmm: bool, top_k: int | None, follow: bool,
             idle_timeout: float | None) -> None:
    """Predict the place of every query with a saved MODEL.

    \b
    Batch:  btel localize MODEL QUERIES.npy -o predictions.csv   (writes query,prediction CSV)
    Stream: producer | btel localize MODEL --stream --sequence-filter 5   (or --hmm)
            btel localize MODEL --stream --input frames.txt --follow
            camera | btel localize MODEL --stream --binary   (float32 frames, see --binary)
    In stream mode each line of input is one descriptor; each output line is the place index of the
    next well-formed input line. A malformed line (wrong count, not a number, NaN) gets a one-line
    error naming its line number on stderr, produces no output line, and the stream goes on.
    """
    from .. import load

    if stream:
        if top_k is not None:
            raise click.UsageError("--top-k applies to batch localization, not --stream.")
        if hmm and window is not None:
            raise click.UsageError("choose --hmm or --sequence-filter, not both.")
        if queries is not None or output is not None:
            raise click.UsageError("--stream reads stdin (or --input) and writes stdout; drop QUERIES and -o.")
        _localize_stream(load(model_path), input_path, follow, idle_timeout, window, hmm, binary)
        return
    if input_path is not None or follow or idle_timeout is not None or binary:
        raise click.UsageError("--input, --follow, --idle-timeout and --binary only apply with --stream.")
    if queries is None or output is None:
        raise click.UsageError("give QUERIES and -o/--output (or use --stream).")
    if hmm and window is not None:
        raise click.UsageError("choose --hmm or --sequence-filter, not both.")
    refuse_existing(output, "-o", overwrite)
    model = load(model_path)
    Q = _load_matrix(queries, "query descriptors")
    predictions = model.predict_sequence(Q, "hmm") if hmm else model.predict(Q)
    if window is not None:
        from ..sequence.filter import filter_sequence

        predictions = filter_sequence(predictions, window, n_places=model.n_places_)
    ranked = model.rank(Q, top_k) if top_k is not None else None
    Path(output).parent.mkdir(parents=True, exist_ok=True)
    from ..core.claims import atomic_output

    # Whole or not at all; without --overwrite a file another process wrote meanwhile is kept.
    with atomic_output(output, overwrite=overwrite, text=True) as fh:
        writer = csv.writer(fh)
        head = ["query", "prediction"]
        if ranked is not None:
            head += [f"rank_{j + 1}" for j in range(ranked.shape[1])]
        writer.writerow(head)
        for i, p in enumerate(predictions.tolist()):
            writer.writerow([i, p, *(ranked[i].tolist() if ranked is not None else [])])
    click.echo(f"{len(predictions)} predictions written to {output}")


def _localize_stream(model: Any, input_path: str | None, follow: bool, idle_timeout: float | None,
                     window: int | None, hmm: bool = False, binary: bool = False) -> None:
    """The --stream loop: one output line per well-formed input line, flushed before more input is awaited."""
    from ..sequence.streaming import localize_stream

    if follow and input_path is None:
        raise click.UsageError("--follow needs --input FILE (stdin already waits for new lines).")
    if idle_timeout is not None and not follow:
        raise click.UsageError("--idle-timeout only applies with --follow.")
    n_bad = n_out = 0
    unit = "frame" if binary else "line"

    def report(line_number: int, message: str) -> None:
        nonlocal n_bad
        n_bad += 1
        click.echo(f"error: {unit} {line_number}: {message} (skipped)", err=True)

    # Bytes, decoded line by line in localize_stream: a byte that is not UTF-8 is one malformed line,
    # not the end of the stream (a text stream's decoder would raise and stop it).
    source = open(input_path, "rb") if input_path is not None else getattr(sys.stdin, "buffer", sys.stdin)
    out = sys.stdout
    try:
        for _, place in localize_stream(model, source, window=window, on_error=report, follow=follow, hmm=hmm,
                                        idle_timeout=idle_timeout, binary=binary, on_flush=out.flush):
            out.write(f"{place}\n")  # flushed by on_flush: a reader of the pipe sees each answer at once
            n_out += 1
    except KeyboardInterrupt:  # stopping a --follow stream is the normal way to end it
        pass
    finally:
        if input_path is not None:
            source.close()
    if n_bad:
        click.echo(f"{n_out} predictions; {n_bad} malformed {unit}(s) skipped", err=True)
