"""VPR-methods-evaluation conventions: ``database/`` and ``queries/`` folders, UTM in the file names.

The most used VPR harness (gmberton/VPR-methods-evaluation) reads a data set folder with two
image folders, ``database/`` (the map) and ``queries/``, whose file names carry each image's
position: ``@utm_east@utm_north@…`` (``@0543256.96@4178906.70@10@S@….jpg``: the first two fields
after the leading ``@`` are UTM east and north in metres). A query's positives are the map images
within ``--positive-dist-threshold`` metres (25 by default there).

Image names also become structure when btel writes them: one pair per line in an hloc pairs file
(names separated by a space), one row per line in a CSV, a file name in a folder for a gallery.
:func:`check_image_names` refuses, naming it, any name that would change that structure.

>>> utm_from_name("@0543256.96@4178906.70@10@S@037.75@-122.50@.jpg")
(543256.96, 4178906.7)
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from ..exceptions import InvalidParameterError

__all__ = ["DEFAULT_POSITIVE_DIST_THRESHOLD", "utm_from_name", "utm_of_names", "split_dataset_folder",
           "check_image_names"]

#: Metres within which a map image is a positive of a query (VPR-methods-evaluation's default).
DEFAULT_POSITIVE_DIST_THRESHOLD = 25.0


def utm_from_name(name: str) -> tuple[float, float]:
    """(east, north) in metres from a VPR-methods-evaluation file name ``@east@north@…``.

    Raises
    ------
    InvalidParameterError
        The name does not start with ``@east@north@`` (two numbers).
    """
    base = Path(str(name)).name
    fields = base.split("@")
    try:
        if fields[0] != "" or len(fields) < 4:
            raise ValueError
        return float(fields[1]), float(fields[2])
    except ValueError:
        raise InvalidParameterError(
            f"image name {base!r} carries no UTM position; VPR-methods-evaluation names start with "
            "@utm_east@utm_north@ (e.g. @0543256.96@4178906.70@10@S@….jpg).") from None


def utm_of_names(names: Sequence[str], what: str) -> np.ndarray:
    """UTM (east, north) of every name, shape (n, 2) float64; ``what`` names the set in errors."""
    if not names:
        raise InvalidParameterError(f"{what}: no image names to read UTM positions from.")
    try:
        return np.array([utm_from_name(n) for n in names], dtype=np.float64)
    except InvalidParameterError as exc:
        raise InvalidParameterError(f"{what}: {exc}") from None


def split_dataset_folder(folder: str | os.PathLike) -> tuple[Path, Path] | None:
    """(database, queries) folders when ``folder`` is a VPR-methods-evaluation data set, else None."""
    folder = Path(folder)
    db, q = folder / "database", folder / "queries"
    return (db, q) if db.is_dir() and q.is_dir() else None


def check_image_names(names: Sequence[str], what: str, *, space: bool = True,
                      file_name: bool = False) -> None:
    """Refuse an image name that would change the structure of the file btel writes it into.

    Every name must be a non-empty string of printable characters (:meth:`str.isprintable`: no
    control, format or line/paragraph separator character, no whitespace but the ASCII space).

    Parameters
    ----------
    names : sequence of str
        The names, in row order.
    what : str
        Where they come from, for the message (``"--db db.h5:db/"``).
    space : bool, default True
        Whether a name may hold a space (False for hloc pairs files, which split on whitespace).
    file_name : bool, default False
        Whether each name must be a plain file name in a folder (no ``/``, not ``.`` or ``..``),
        as for the images a gallery opens.

    Raises
    ------
    InvalidParameterError
        The first offending name, its row and the character that is not allowed.
    """
    for row, name in enumerate(names):
        if not isinstance(name, str) or not name:
            raise InvalidParameterError(
                f"{what}: the image name of row {row} is empty ({name!r}); name every image.")
        if name.isprintable() and (space or " " not in name) and not (
                file_name and ("/" in name or os.sep in name or name in (".", ".."))):
            continue
        bad = next((c for c in name if not c.isprintable() or (c == " " and not space)), None)
        kind = "a space" if bad == " " else "a control or separator character"
        reason = (f"holds U+{ord(bad):04X} ({kind})" if bad is not None else
                  "is not a plain file name in its folder")
        rule = ("hloc pairs files separate names by spaces, one pair per line" if bad == " " else
                "btel writes image names one per line into pairs files and CSVs" if bad is not None else
                "a gallery opens the images inside the folder the .json names")
        raise InvalidParameterError(
            f"{what}: image name {name[:200]!r} (row {row}) {reason}; {rule}. Rename that image.")
