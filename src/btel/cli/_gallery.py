"""Image names in the predictions and the match gallery of a run (``btel evaluate``, ``btel show``).

Descriptors written by ``btel extract`` record their images (names, and the folder since this
version) in the ``.json`` beside them; a run records its ``--db`` and ``--queries``. From those a
finished run folder can show what each method retrieved: ``gallery_<method>.png``.
"""

from __future__ import annotations

import csv
import json
from pathlib import Path
from typing import Any

import click

#: Queries shown in a gallery (rows of the figure).
GALLERY_ROWS = 8


def input_names(db: str | None, queries: str, n_map: int, n_queries: int) -> tuple[list[str] | None, list[str] | None]:
    """The image names of the query rows and of the map rows, each None when unknown or not one per row."""
    from ..datasets.vpr_names import check_image_names
    from ._names import row_names

    q_names = row_names(queries)
    db_names = row_names(db) if db else None
    q_names = q_names if q_names is not None and len(q_names) == n_queries else None
    db_names = db_names if db_names is not None and len(db_names) == n_map else None
    for option, path, names in (("--queries", queries, q_names), ("--db", db, db_names)):
        if names is not None:  # they go into the predictions CSV, one row per line
            check_image_names(names, f"{option} {path}")
    return q_names, db_names


def row_images(path: str | None) -> list[Path] | None:
    """The image file of every row of the descriptors ``path`` (from ``btel extract``'s .json), or
    None when they are not recorded or no longer on disk. A recorded name that is not a plain file
    name (``../x``, a control character) raises :class:`~btel.exceptions.InvalidParameterError`."""
    from ..datasets.vpr_names import check_image_names

    if not path:
        return None
    sidecar = Path(str(path) + ".json")
    try:
        key = json.loads(sidecar.read_text(encoding="utf-8"))
        folder = key.get("folder")
        names = [str(entry[0]) for entry in key["images"]] if folder else None
    except (OSError, ValueError, AttributeError, TypeError, IndexError, KeyError):
        return None
    if names is None:
        return None
    check_image_names(names, str(sidecar), file_name=True)  # images inside the folder, nowhere else
    files = [Path(folder) / name for name in names]
    if not files or not all(f.is_file() for f in files):
        return None
    return files


def _read_predictions(path: Path) -> dict[str, Any] | None:
    """Top-1, a true place and correctness per query from a ``predictions_<method>.csv``."""
    import numpy as np

    with open(path, newline="", encoding="utf-8") as fh:
        reader = csv.DictReader(fh)
        fields = reader.fieldnames or []
        rows = list(reader)
    if not rows or "prediction" not in fields:
        return None
    pred = np.array([int(r["prediction"]) for r in rows], dtype=np.int64)
    true_field = "true" if "true" in fields else "positive" if "positive" in fields else None
    if true_field is None:
        return None
    true = np.array([int(r[true_field]) for r in rows], dtype=np.int64)
    correct = (np.array([int(r["correct"]) for r in rows], dtype=bool) if "correct" in fields else pred == true)
    return {"pred": pred, "true": true, "correct": correct,
            "label": "true place" if true_field == "true" else "a positive"}


def write_galleries(run: Path, *, n_rows: int = GALLERY_ROWS, overwrite: bool = True) -> list[Path]:
    """Draw ``gallery_<method>.png`` in the run folder ``run`` for every method with predictions,
    when the run's ``--db`` and ``--queries`` record their images. Returns the files written.

    Raises
    ------
    click.ClickException
        ``run`` has no metrics.json, or the images of its inputs are not recorded / not on disk
        (the message says which).
    """
    from ..evaluation.gallery import plot_match_gallery

    meta_path = run / "metrics.json"
    if not meta_path.is_file():
        raise click.ClickException(f"{run} has no metrics.json; give a run folder written by btel evaluate.")
    try:
        payload = json.loads(meta_path.read_text(encoding="utf-8"))
        extra = payload["run"].get("extra") or {}
        names = [r["name"] for r in payload["results"] if r.get("status", "ok") == "ok"]
    except (ValueError, KeyError, TypeError, AttributeError) as exc:
        raise click.ClickException(f"{meta_path} is not a btel run's metrics ({exc}).") from None
    db, queries = extra.get("db"), extra.get("queries")
    q_images, db_images = row_images(queries), row_images(db)
    if q_images is None or db_images is None:
        missing = [f"{option} {path}" if path else f"{option} (not given)" for option, path, images in (("--db", db, db_images),
                                                                    ("--queries", queries, q_images))
                   if images is None]
        raise click.ClickException(
            f"the match gallery needs the images of the run's inputs, and {' and '.join(missing)} "
            f"{'records' if len(missing) == 1 else 'record'} none on disk (descriptors written by btel extract record their image folder in the .json "
            "beside them; a --model run has no --db images).")
    from ..evaluation.runs import safe_file_name

    written = []
    for name in names:
        predictions = run / f"predictions_{safe_file_name(name)}.csv"
        read = _read_predictions(predictions) if predictions.is_file() else None
        if read is None or read["pred"].shape[0] != len(q_images):
            continue
        target = run / f"gallery_{safe_file_name(name)}.png"
        if target.exists() and not overwrite:
            raise click.UsageError(f"{target} already exists; give --overwrite to draw it again.")
        written.append(plot_match_gallery(q_images, db_images, read["pred"], read["true"], read["correct"], target,
                                          n_rows=n_rows, title=f"{name} — {run.name}",
                                          true_label=read["label"]))
    return written


def galleries_after_run(run: Path, extra: dict[str, Any]) -> None:
    """``btel evaluate`` on image inputs: draw the galleries of the finished run ``run``. An image
    that cannot be read costs the figure only (a warning): the run is already written."""
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
    """Draw the match gallery of each method of the finished run folder RUN: gallery_<method>.png.

    Each row: a query image | its top-1 retrieved map image (green frame: correct, red: wrong) |
    the true place's map image. Needs a run of descriptors written by `btel extract` from image
    folders (their .json records the images) whose images are still on disk.
    """
    written = write_galleries(Path(run), n_rows=n_rows, overwrite=overwrite)
    if not written:
        raise click.ClickException(f"{run}: no method's predictions name a true place to show.")
    for path in written:
        click.echo(f"gallery: {path}")
