"""The match gallery of a run (``btel evaluate``, ``btel show``): what each method retrieved,
``gallery_<method>.png``, drawn from the images that the run's ``--db`` and ``--queries`` record
(:func:`btel.datasets.row_names.row_images`)."""

from __future__ import annotations

import csv
import os
from pathlib import Path
from typing import Any

import click

from ._errors import InputError

#: Queries shown in a gallery (rows of the figure).
GALLERY_ROWS = 8


#: Largest predictions CSV read (64 MiB, as metrics.json: a million queries' rows of ten candidates).
_MAX_PREDICTIONS_BYTES = 64 << 20


def _cell(text: str, low: int, high: int) -> int | None:
    """The integer ``text`` if it is one in ``[low, high)``, else None."""
    try:
        value = int(text)
    except ValueError:  # not a number, or more digits than int() reads
        return None
    return value if low <= value < high else None


def _read_predictions(path: Path, n_queries: int, n_map: int) -> dict[str, Any] | None:
    """Top-1, a true place and correctness per query from a ``predictions_<method>.csv`` of a run of
    ``n_queries`` queries on ``n_map`` map images; None when it has no such columns or not ``n_queries``
    rows (a run on other queries: no gallery for it).

    Raises
    ------
    InputError
        A row that btel never writes (cut short, a cell that is no integer), or a file that is no CSV,
        not UTF-8, or larger than btel writes: the message names the file, the row and the fix.
    """
    import io

    import numpy as np

    from ..core.limits import open_regular
    from ..exceptions import DataNotFoundError

    fix = "run `btel evaluate` again to write it, or remove it to draw the other methods' galleries"
    columns: dict[str, list[int]] = {}
    try:
        with open_regular(path) as raw:  # a FIFO here would block `btel show` forever
            data = raw.read(_MAX_PREDICTIONS_BYTES + 1)
        if len(data) > _MAX_PREDICTIONS_BYTES:
            raise InputError(f"{path} holds more than {_MAX_PREDICTIONS_BYTES >> 20} MiB, more than btel writes "
                             f"for a run's predictions; {fix}.")
        reader = csv.DictReader(io.StringIO(data.decode("utf-8"), newline=""))
        fields = reader.fieldnames or []
        true_field = "true" if "true" in fields else "positive" if "positive" in fields else None
        if "prediction" not in fields or true_field is None:
            return None
        wanted = ["prediction", true_field, *(["correct"] if "correct" in fields else [])]
        columns = {field: [] for field in wanted}
        for row in reader:
            if len(columns["prediction"]) == n_queries:  # more rows than queries: not this run's; read no further
                return None
            if None in row or None in row.values():  # a long row keeps its surplus under None, a short one None
                raise InputError(f"{path}, line {reader.line_num}: the row has {'more' if None in row else 'fewer'} "
                                 f"cells than the header's {len(fields)}, which btel never writes (the file was "
                                 f"edited or damaged); {fix}.")
            for field in wanted:
                value = _cell(row[field], -1 if field != "correct" else 0, n_map if field != "correct" else 2)
                if value is None:
                    raise InputError(
                        f"{path}, line {reader.line_num}: {field} is {row[field]!r:.40}, which btel never writes "
                        f"(an integer from {-1 if field != 'correct' else 0} to {(n_map if field != 'correct' else 2) - 1}"
                        f"): the file was edited or damaged; {fix}.")
                columns[field].append(value)
    except DataNotFoundError as exc:
        raise InputError(f"{exc} {fix[0].upper()}{fix[1:]}.") from None
    except (csv.Error, UnicodeDecodeError) as exc:
        raise InputError(f"{path} is not a btel predictions CSV ({exc}); {fix}.") from None
    pred = np.array(columns["prediction"], dtype=np.int64)
    if pred.shape[0] != n_queries:
        return None
    true = np.array(columns[true_field], dtype=np.int64)
    correct = np.array(columns["correct"], dtype=bool) if "correct" in columns else pred == true
    return {"pred": pred, "true": true, "correct": correct,
            "label": "true place" if true_field == "true" else "a positive"}


def _run_names(meta_path: Path) -> tuple[dict[str, Any], list[str]]:
    """The ``extra`` metadata of the run ``metrics.json`` at ``meta_path`` and the names of its rows done."""
    from ..evaluation.runfile import read_run_payload
    from ..exceptions import BTELError

    fix = "run `btel evaluate` again to write the run anew"
    try:
        run, results = read_run_payload(meta_path, fix)
    except BTELError as exc:
        raise InputError(str(exc)) from None
    extra = run.get("extra") or {}
    if not isinstance(extra, dict) or not all(isinstance(extra.get(k), (str, type(None))) for k in ("db", "queries")):
        raise InputError(f"{meta_path}: run.extra must be an object whose db and queries are paths (or null), as "
                         f"btel writes it (the file was edited or damaged); {fix}.")
    names = []
    for i, row in enumerate(results):
        if not isinstance(row, dict) or not isinstance(row.get("name"), str) or not isinstance(
                row.get("status", "ok"), str):
            raise InputError(f"{meta_path}: results[{i}] must be an object whose name and status are strings, as "
                             f"btel writes it (the file was edited or damaged); {fix}.")
        if row.get("status", "ok") == "ok":
            names.append(row["name"])
    return extra, names


class NoImagesError(InputError):
    """The run's inputs record no images on disk, so it has no match gallery to draw."""


def write_galleries(run: Path, *, n_rows: int = GALLERY_ROWS, overwrite: bool = True,
                    kept: list[Path] | None = None) -> list[Path]:
    """Draw ``gallery_<method>.png`` in the run folder ``run`` for every method with predictions,
    when the run's ``--db`` and ``--queries`` record their images. Returns the files written; a gallery
    already there is replaced only with ``overwrite``, else appended to ``kept``.

    Raises
    ------
    InputError
        ``run`` has no metrics.json, or a file of it is damaged (the message names it).
    NoImagesError
        The images of its inputs are not recorded or not on disk (the message says which).
    """
    from ..datasets.row_names import row_images
    from ..evaluation.gallery import plot_match_gallery

    meta_path = run / "metrics.json"
    if not os.path.lexists(meta_path):  # a FIFO or folder there: refused by the reader, never waited on
        raise InputError(f"{run} has no metrics.json; give a run folder written by btel evaluate.")
    extra, names = _run_names(meta_path)
    db, queries = extra.get("db"), extra.get("queries")
    if db is None and queries is None:
        raise NoImagesError(f"{run} records no input files: its descriptors were generated or loaded by btel itself "
                         "(btel demo, btel experiment), so it has no images to show; the match gallery is drawn for "
                         "a `btel evaluate` run on descriptors written by `btel extract` (they record their images).")
    q_images, db_images = row_images(queries), row_images(db)
    if q_images is None or db_images is None:
        missing = [f"{option} {path}" if path else f"{option} (not given)" for option, path, images
                   in (("--db", db, db_images), ("--queries", queries, q_images)) if images is None]
        raise NoImagesError(
            f"the match gallery needs the images of the run's inputs, and {' and '.join(missing)} "
            f"{'records' if len(missing) == 1 else 'record'} none on disk (descriptors written by btel extract "
            "record their image folder in the .json beside them; a --model run has no --db images).")
    from ..evaluation.runs import safe_file_name

    written = []
    for name in names:
        predictions = run / f"predictions_{safe_file_name(name)}.csv"
        read = _read_predictions(predictions, len(q_images), len(db_images)) if os.path.lexists(predictions) else None
        if read is None:
            continue
        target = run / f"gallery_{safe_file_name(name)}.png"
        if target.exists() and not overwrite:
            if kept is not None:
                kept.append(target)
            continue
        written.append(plot_match_gallery(q_images, db_images, read["pred"], read["true"], read["correct"], target,
                                          n_rows=n_rows, title=f"{name} — {run.name}",
                                          true_label=read["label"]))
    return written


def galleries_after_run(run: Path, extra: dict[str, Any]) -> None:
    """``btel evaluate`` on image inputs: draw the galleries of the finished run ``run``. An image
    that cannot be read costs the figure only (a warning): the run is already written."""
    from ..datasets.row_names import row_images
    from ..exceptions import BTELError

    try:
        if not (row_images(extra.get("queries")) and row_images(extra.get("db"))):
            return
        for path in write_galleries(run):
            click.echo(f"match gallery: {path}")
    except (click.ClickException, BTELError, OSError) as exc:
        click.echo(f"Warning: the match gallery could not be drawn ({getattr(exc, 'message', exc)})", err=True)


@click.command(name="show")
@click.argument("run", type=click.Path(file_okay=False))
@click.option("--rows", "n_rows", type=click.IntRange(min=1, max=50), default=GALLERY_ROWS, show_default=True,
              help="Queries shown per gallery (failures and successes, spread over the query order).")
@click.option("--overwrite", is_flag=True, help="Replace gallery_<method>.png files already in RUN.")
def show_cmd(run: str, n_rows: int, overwrite: bool) -> None:
    """Show what the run folder RUN records, and draw its match galleries.

    \b
    Prints the command and where it ran, when, the btel and library versions, the machine and its
    threads, every input with its fingerprint, the ground truth, the results table and what each fit
    chose. Then, for a run whose descriptors were written by `btel extract` from image folders still
    on disk, draws gallery_<method>.png: each row a query image | its top-1 retrieved map image (green
    frame: correct, red: wrong) | the true place's map image. `btel evaluate` draws them after such a
    run; a gallery already in RUN is kept unless --overwrite.
    """
    from ..evaluation.runfile import describe_run
    from ..evaluation.tables import terminal_width
    from ..exceptions import BTELError

    folder = Path(run)
    if not os.path.lexists(folder / "metrics.json"):  # a FIFO or folder there: refused by the reader
        raise InputError(f"{run} has no metrics.json; give a run folder written by btel evaluate or btel demo.")
    try:
        text = describe_run(folder, terminal_width())
    except BTELError as exc:
        raise InputError(str(exc)) from None
    click.echo(text)
    kept: list[Path] = []
    try:
        written = write_galleries(folder, n_rows=n_rows, overwrite=overwrite, kept=kept)
    except NoImagesError as exc:
        click.echo(f"no match gallery: {exc.message}")
        return
    for path in written:
        click.echo(f"gallery: {path}")
    for path in kept:
        click.echo(f"gallery: {path} (kept; --overwrite draws it again)")
    if not written and not kept:
        click.echo("no match gallery: no method's predictions name a true place to show.")
