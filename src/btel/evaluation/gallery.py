"""Match gallery: what a method retrieved for some queries, next to the true place.

VPR users judge a method by looking at its successes and failures. :func:`plot_match_gallery`
draws one row per query — the query image, its top-1 retrieved map image and the true place's
map image — framed green (correct) or red (wrong), for a bounded, deterministic choice of
queries (failures and successes alike).
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ..exceptions import InvalidParameterError

#: Longest side of every image drawn in the gallery, in pixels (the images are downscaled).
GALLERY_IMAGE_SIDE = 240


def choose_gallery_queries(correct: np.ndarray, n_rows: int = 8) -> np.ndarray:
    """Indices of the queries to show: half failures and half successes (as many as exist), evenly
    spread over the query order, so the same run always gives the same gallery.

    Parameters
    ----------
    correct : ndarray of bool, shape (n_queries,)
        Whether each query's top-1 is a true place.
    n_rows : int, default 8
        Most queries to show.

    Returns
    -------
    ndarray of int64, shape (≤ n_rows,)
        Query indices in increasing order.
    """
    correct = np.asarray(correct, dtype=bool)
    if n_rows < 1:
        raise InvalidParameterError(f"n_rows must be ≥ 1; got {n_rows}.")
    wrong, right = np.flatnonzero(~correct), np.flatnonzero(correct)
    n_wrong = min(wrong.size, max(n_rows // 2, n_rows - right.size))
    n_right = min(right.size, n_rows - n_wrong)

    def spread(pool: np.ndarray, n: int) -> np.ndarray:
        return pool[np.unique(np.linspace(0, pool.size - 1, n).round().astype(np.int64))] if n else pool[:0]

    return np.sort(np.concatenate([spread(wrong, n_wrong), spread(right, n_right)]))


def _thumbnail(path: Path | None) -> np.ndarray | None:
    """The image at ``path`` as RGB uint8, its longest side at most :data:`GALLERY_IMAGE_SIDE`."""
    if path is None:
        return None
    from ..descriptors.images import read_image  # first: it sets OpenCV's pixel cap before cv2 loads

    import cv2

    image = read_image(path)
    scale = GALLERY_IMAGE_SIDE / max(image.shape[:2])
    if scale < 1:
        size = (max(1, round(image.shape[1] * scale)), max(1, round(image.shape[0] * scale)))
        image = cv2.resize(image, size, interpolation=cv2.INTER_AREA)
    return image


def plot_match_gallery(
    query_images: Sequence[str | os.PathLike],
    db_images: Sequence[str | os.PathLike],
    predictions: np.ndarray,
    true_places: np.ndarray,
    correct: np.ndarray,
    path: str | os.PathLike,
    *,
    n_rows: int = 8,
    title: str | None = None,
    true_label: str = "true place",
) -> Path:
    """Draw the match gallery of one method to ``path`` (PNG).

    Parameters
    ----------
    query_images, db_images : sequence of path
        The image file of every query row / map row.
    predictions : ndarray of int, shape (n_queries,)
        Top-1 map row of each query (-1: no answer).
    true_places : ndarray of int, shape (n_queries,)
        A true map row of each query (-1: none known).
    correct : ndarray of bool, shape (n_queries,)
        Whether each query's top-1 is a true place.
    path : path
        The PNG to write.
    n_rows : int, default 8
        Most queries shown (chosen by :func:`choose_gallery_queries`).
    title : str, optional
        Figure title (method and run).
    true_label : str, default "true place"
        What the third image is (``"a positive"`` when the ground truth lists several per query).

    Returns
    -------
    Path
        ``path``.

    Raises
    ------
    InvalidParameterError
        The arrays and image lists disagree in length.
    DataNotFoundError
        An image file is missing or cannot be decoded.
    """
    predictions = np.asarray(predictions, dtype=np.int64)
    true_places = np.asarray(true_places, dtype=np.int64)
    correct = np.asarray(correct, dtype=bool)
    n = len(query_images)
    if not (predictions.shape == true_places.shape == correct.shape == (n,)):
        raise InvalidParameterError(
            f"match gallery: {n} query images but {predictions.shape[0]} predictions, {true_places.shape[0]} true "
            f"places and {correct.shape[0]} correctness flags; they must agree.")
    for name, rows in (("predictions", predictions), ("true places", true_places)):
        if rows.size and (rows.min() < -1 or rows.max() >= len(db_images)):
            raise InvalidParameterError(f"match gallery: {name} point outside the {len(db_images)} map images.")
    chosen = choose_gallery_queries(correct, n_rows)

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(len(chosen), 3, figsize=(9.0, 2.3 * len(chosen) + 0.6), squeeze=False)
    try:
        _draw_rows(axes, chosen, query_images, db_images, predictions, true_places, correct, true_label)
    except BaseException:
        plt.close(fig)
        raise
    n_ok = int(correct[chosen].sum())
    import textwrap

    # Wrapped to the figure's width (about 110 characters of 9-point text on 9 inches): one long line
    # was cut at both edges; the rows are laid out below the title's lines, not under them.
    text = "\n".join(textwrap.fill(line, 110, break_on_hyphens=False) for line in [*([title] if title else []),
                      f"top-1 over all {n} queries: {correct.mean():.0%}. Shown: {len(chosen)} of them, half right "
                      f"and half wrong where there are enough of each: {n_ok} correct (green), "
                      f"{len(chosen) - n_ok} wrong (red)"])
    fig.suptitle(text, fontsize=9, parse_math=False)
    height = fig.get_figheight()
    fig.tight_layout(rect=(0.0, 0.0, 1.0, 1.0 - (0.14 * (text.count("\n") + 1) + 0.02) / height))
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    from ..core.claims import atomic_output

    try:
        with atomic_output(path, suffix=".tmp") as fh:  # a full disk leaves no half-written figure
            fig.savefig(fh, dpi=100, format="png")
    finally:
        plt.close(fig)
    return path


def _draw_rows(axes: Any, chosen: np.ndarray, query_images: Sequence[Any], db_images: Sequence[Any],
               predictions: np.ndarray, true_places: np.ndarray, correct: np.ndarray, true_label: str) -> None:
    """One row of the gallery per chosen query: query | top-1 (framed by its verdict) | true place."""
    for row, j in zip(axes, chosen.tolist()):
        ok = bool(correct[j])
        colour = "#1a9641" if ok else "#d7191c"
        cells = [(Path(query_images[j]), f"query {j}", "black"),
                 (Path(db_images[predictions[j]]) if predictions[j] >= 0 else None,
                  f"top-1: map {predictions[j]} — {'correct' if ok else 'wrong'}", colour),
                 (Path(db_images[true_places[j]]) if true_places[j] >= 0 else None,
                  f"{true_label}: map {true_places[j]}" if true_places[j] >= 0 else f"no {true_label}", "black")]
        for ax, (image_path, label, text_colour) in zip(row, cells):
            image = _thumbnail(image_path)
            if image is not None:
                ax.imshow(image)
            else:
                ax.text(0.5, 0.5, "—", ha="center", va="center", fontsize=20, transform=ax.transAxes)
            ax.set_xticks([])
            ax.set_yticks([])
            ax.set_title(label + (f"\n{image_path.name}" if image_path is not None else ""), fontsize=8,
                         color=text_colour, parse_math=False)  # a "$" in a file name is text, not TeX
        for spine in row[1].spines.values():  # the retrieved image carries the verdict as its frame
            spine.set_edgecolor(colour)
            spine.set_linewidth(4)
