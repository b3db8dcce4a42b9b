"""The match gallery of a run (``btel evaluate``, ``btel show``): what each method retrieved,
``gallery_<method>.png``, drawn from the images that the run's ``--db`` and ``--queries`` record
(:func:`btel.datasets.row_names.row_images`)."""

from __future__ import annotations

import csv
import json
from pathlib import Path
from typing import Any

import click

from ._errors import InputError

#: Queries shown in a gallery (rows of the figure).
GALLERY_ROWS = 8


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
    InputError
        ``run`` has no metrics.json, or the images of its inputs are not recorded / not on disk
        (the message says which).
    """
    from ..datasets.row_names import row_images
    from ..evaluation.gallery import plot_match_gallery

    meta_path = run / "metrics.json"
    if not meta_path.is_file():
        raise InputError(f"{run} has no metrics.json; give a run folder written by btel evaluate.")
    try:
        payload = json.loads(meta_path.read_text(encoding="utf-8"))
        extra = payload["run"].get("extra") or {}
        names = [r["name"] for r in payload["results"] if r.get("status", "ok") == "ok"]
    except (ValueError, KeyError, TypeError, AttributeError) as exc:
        raise InputError(f"{meta_path} is not a btel run's metrics ({exc}).") from None
    db, queries = extra.get("db"), extra.get("queries")
    q_images, db_images = row_images(queries), row_images(db)
    if q_images is None or db_images is None:
        missing = [f"{option} {path}" if path else f"{option} (not given)" for option, path, images
                   in (("--db", db, db_images), ("--queries", queries, q_images)) if images is None]
        raise InputError(
            f"the match gallery needs the images of the run's inputs, and {' and '.join(missing)} "
            f"{'records' if len(missing) == 1 else 'record'} none on disk (descriptors written by btel extract "
            "record their image folder in the .json beside them; a --model run has no --db images).")
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
    """Draw the match gallery of each method of the finished run folder RUN: gallery_<method>.png.

    Each row: a query image | its top-1 retrieved map image (green frame: correct, red: wrong) |
    the true place's map image. Needs a run of descriptors written by `btel extract` from image
    folders (their .json records the images) whose images are still on disk.
    """
    written = write_galleries(Path(run), n_rows=n_rows, overwrite=overwrite)
    if not written:
        raise InputError(f"{run}: no method's predictions name a true place to show.")
    for path in written:
        click.echo(f"gallery: {path}")
