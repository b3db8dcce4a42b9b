"""Output files of the ``btel`` commands: nothing existing is replaced without ``--overwrite``.

Every command that writes a file checks it before doing any work; the refusal says what the file
holds (so a user sees what would have been lost) and how to go on.
"""

from __future__ import annotations

from pathlib import Path

import click


def describe_file(path: Path) -> str:
    """A few words on what ``path`` holds: an array's shape, a model's method, a CSV's rows, else its size."""
    size = path.stat().st_size
    what = f"{size:,d} B"
    suffix = path.suffix.lower()
    try:
        if suffix == ".npy":
            import numpy as np

            array = np.load(path, mmap_mode="r", allow_pickle=False)
            what = f"a {' × '.join(map(str, array.shape))} {array.dtype} matrix, {size:,d} B"
            from ..descriptors.npy_header import read_sidecar

            key = read_sidecar(path)  # bounded: a regular file of at most MAX_SIDECAR_BYTES
            if isinstance(key, dict):
                images = key.get("images") or []
                what += f"; {key.get('descriptor', '?')} descriptors of {len(images)} images"
                if images:
                    what += f" ({images[0][0]} … {images[-1][0]})"
        elif suffix == ".npz":
            import zipfile

            with zipfile.ZipFile(path) as zf:
                names = [n.removesuffix(".npy") for n in zf.namelist()]
            what = f"an .npz archive of {len(names)} arrays, {size:,d} B"
        elif suffix in (".csv", ".txt"):
            with open(path, "rb") as fh:
                n_lines = sum(1 for _ in fh)
            what = f"{n_lines:,d} lines, {size:,d} B"
    except Exception:  # noqa: BLE001 - a description is best effort; the refusal stands either way
        pass
    return what


def refuse_existing(path: str | Path, option: str, overwrite: bool,
                    inputs: dict[str, str | None] | None = None) -> None:
    """Raise a usage error when ``path`` exists and ``overwrite`` is not set, or is one of the command's inputs.

    Parameters
    ----------
    path : path
        The file the command is about to write.
    option : str
        The option that named it (``-o``, ``--pairs``), for the message.
    overwrite : bool
        ``--overwrite`` given: replacing is intended.
    inputs : dict, optional
        The command's input files by the argument that names them (``{"DB": "db.npz:map"}``): the output may
        be none of them, ``--overwrite`` or not (``btel train db.npz -o db.npz --overwrite`` replaced the map).
    """
    from ..core.claims import refuse_special_target
    from ..descriptors.npy import split_prefix
    from ..exceptions import OutputExistsError

    path = Path(path)
    try:  # before anything is fitted or read: a device or FIFO is never replaced, --overwrite or not
        refuse_special_target(path)
    except OutputExistsError as exc:
        raise click.UsageError(f"{option} {exc}") from None
    for name, given in (inputs or {}).items():
        source = None if given is None else Path(given) if Path(given).exists() else split_prefix(given)[0]
        try:
            same = source is not None and path.exists() and source.is_file() and path.samefile(source)
        except OSError:
            same = False
        if same:
            raise click.UsageError(f"{option} {path} is also the input {name}: writing it would destroy that input. "
                                   "Give another file name.")
    if overwrite or not path.exists():
        return
    if path.is_dir():
        raise click.UsageError(f"{option} {path} is a folder; give a file name.")
    raise click.UsageError(f"{option} {path} already exists ({describe_file(path)}); give --overwrite to replace it, "
                           "or another file name.")


#: Suffixes that name a format other than a btel model: a model written under one would be misread by
#: whoever trusts the name (np.load of a ".npy", a spreadsheet of a ".csv", `btel localize` taking it for
#: descriptors).
OTHER_FORMATS = (".npy", ".csv", ".tsv", ".txt", ".json", ".h5", ".hdf5", ".png", ".jpg", ".jpeg", ".pdf")


def check_output_suffix(path: str | Path, option: str, writes: str, suffixes: tuple[str, ...], *,
                        refused: tuple[str, ...] | None = None) -> None:
    """Raise a usage error when ``path``'s suffix names another format than the one the command writes.

    Parameters
    ----------
    path : path
        The file the command is about to write.
    option : str
        The option that named it (``-o``), for the message.
    writes : str
        What the command writes, e.g. ``"a predictions CSV"``.
    suffixes : tuple of str
        The suffixes it writes (lower case, with the dot); the first is the one suggested.
    refused : tuple of str, optional
        Refuse only these suffixes (any other name is accepted); default: refuse every suffix not in
        ``suffixes``, no suffix included.
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix in suffixes or (refused is not None and suffix not in refused):
        return
    named = f"names a {suffix} file" if suffix else "has no suffix"
    raise click.UsageError(f"{option} {path} {named}, but this command writes {writes} "
                           f"({' or '.join(suffixes)}); name it e.g. {path.with_suffix(suffixes[0])}.")

