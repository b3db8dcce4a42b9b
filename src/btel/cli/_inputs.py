"""Reading descriptor matrices named on the command line: .npy, .npz[:KEY], hloc .h5[:PREFIX], shard folders."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

import click

if TYPE_CHECKING:  # numpy is imported by the commands that need it: `btel --help` does not wait for it
    import numpy as np


def _load_matrix(path: str, what: str, *, mmap: bool = False) -> np.ndarray:
    """The descriptor matrix at ``path``; a refusal says which input it was (``what``: its role). With
    ``mmap``, a ``.npy`` is memory-mapped (a view of the file when it is float32 and C-ordered)."""
    from ..descriptors.npy import load_descriptor_matrix
    from ..exceptions import InvalidDescriptorsError

    mapped = mmap and Path(path).suffix.lower() == ".npy" and Path(path).is_file()
    try:
        return (_load_whole_h5(path, what) if _is_whole_h5(path) else
                load_descriptor_matrix(path, mmap_mode="r" if mapped else None))
    except InvalidDescriptorsError as exc:
        raise InvalidDescriptorsError(f"{what}: {exc}") from None


def declared_rows(path: str) -> int | None:
    """The rows a ``.npy`` file's header announces (None for any other input): checked against what they
    would cost before the file is read, since reading checks every value (hours for a sparse 10¹⁰-row file)."""
    from ..descriptors.npy_header import npy_header

    header = npy_header(path) if Path(path).suffix.lower() == ".npy" else None
    # A file shorter than its header says is named as cut short by the reader, whatever its rows.
    return header[0][0] if header is not None and len(header[0]) == 2 and header[3] >= header[2] else None


def _is_whole_h5(path: str) -> bool:
    from ..descriptors.npy import HDF5_SUFFIXES, split_prefix

    file, prefix = split_prefix(path)
    return prefix is None and file.suffix.lower() in HDF5_SUFFIXES


def _load_whole_h5(path: str, what: str) -> np.ndarray:
    """An hloc .h5 given without a PREFIX: refused when its images sit under several prefixes (map and
    queries in one file, hloc's usual layout), which would otherwise be read as one set."""
    from ..descriptors.npy import load_hloc_global

    X, names = load_hloc_global(path)
    counts: dict[str, int] = {}
    for name in names:
        head, slash, _ = name.partition("/")
        key = head + slash if slash else ""  # images at the top level are one set, not one prefix each
        counts[key] = counts.get(key, 0) + 1
    if len(counts) > 1:
        shown = list(counts.items())[:4]  # a few prefixes name the problem; thousands would flood the line
        found = ", ".join(f"{p or '(top level)'} {n} images" for p, n in shown) + (" …" if len(counts) > 4 else "")
        choices = " or ".join(f"{path}:{p}" for p, _ in shown if p)
        raise click.UsageError(f"{path} ({what}) holds images under {len(counts)} prefixes ({found}); name the "
                               f"ones you mean, e.g. {choices}.")
    return X


def _load_map(path: str) -> np.ndarray:
    """Map descriptors for training: a folder of .npy shards, a memory-mapped .npy, an .npz or an hloc .h5."""
    if Path(path).is_dir():
        from ..datasets.shards import load_shards

        _refuse_image_folder(path)

        return load_shards(path)
    if _is_whole_h5(path):
        return _load_whole_h5(path, "map descriptors")
    from ..descriptors.npy import load_descriptor_matrix

    # A .npy map is memory-mapped: pages are read as the fit needs them, never copied whole.
    return load_descriptor_matrix(path, mmap_mode="r" if Path(path).suffix.lower() == ".npy" else None)


def _refuse_image_folder(path: str) -> None:
    """A folder of images (no .npy shards) given as DB: name the step that turns them into descriptors
    (the shard reader alone would only say that no .npy shard is there)."""
    from ..descriptors.images import IMAGE_EXTENSIONS

    files = [p for p in Path(path).iterdir() if p.is_file() and not p.name.startswith(".")]
    images = [p for p in files if p.suffix.lower() in IMAGE_EXTENSIONS]
    if images and not any(p.suffix.lower() == ".npy" for p in files):
        example = min(p.name for p in images)
        raise click.UsageError(f"DB {path} holds images ({len(images)}, e.g. {example}), not descriptors; "
                               f"describe them first with `btel extract {path} -o descriptors.npy`, then train "
                               "on descriptors.npy.")


def load_model(path: str, usage: str = "usage: btel localize MODEL QUERIES -o predictions.csv") -> Any:
    """:func:`btel.load`, with a descriptor matrix given as MODEL (the map or the queries instead of the
    model: arguments swapped) named as such instead of as a corrupt model file (``usage``: the command's)."""
    from .. import load
    from ..exceptions import ModelFileError

    try:
        return load(path)
    except ModelFileError:
        refuse_matrix_as_model(path, "MODEL", usage)
        raise


def refuse_matrix_as_model(path: str, option: str, usage: str) -> None:
    """A usage error when ``path``, given as ``option`` where a model file goes, holds a descriptor matrix
    (``usage`` says where the model goes); nothing when it does not (its load error stands)."""
    found = _matrix_in(path)
    if found is None:
        return
    (rows, columns), dtype, keys = found
    # An .npz of several arrays is read as PATH:KEY (the map's array); name them so the command runs as given.
    source = f"{path}:{keys[0]}" if len(keys) > 1 else path
    among = f" (it holds {', '.join(keys[:6])}: give the map's after the colon)" if len(keys) > 1 else ""
    raise click.UsageError(
        f"{option} {path} looks like a descriptor matrix ({rows} × {columns} {dtype}), not a model. {option} is "
        f"the .npz written by `btel train` ({usage}); to make one from these map descriptors: "
        f"btel train {source} -o model.npz{among}.")


def _matrix_in(path: str) -> tuple[tuple[int, int], str, list[str]] | None:
    """Shape and dtype of the (first) 2-D numeric array in a .npy file, or in an .npz without btel's model
    header, and the .npz's array names (empty for a .npy); None for anything else. Only headers are read
    (the file may be a large map)."""
    import zipfile

    import numpy as np

    from ..core.limits import check_zip_members
    from ..core.modelfile import HEADER_KEY

    readers = {(1, 0): np.lib.format.read_array_header_1_0, (2, 0): np.lib.format.read_array_header_2_0}

    def matrix(fh: Any) -> tuple[tuple[int, int], str] | None:
        reader = readers.get(np.lib.format.read_magic(fh))
        shape, _, dtype = reader(fh) if reader else ((), False, np.dtype(object))
        return (shape, str(dtype)) if len(shape) == 2 and dtype.kind in "fiu" else None

    if not Path(path).is_file():  # a FIFO or a device would block the read below
        return None
    try:
        with open(path, "rb") as fh:
            if fh.read(6) == b"\x93NUMPY":
                fh.seek(0)
                found = matrix(fh)
                return None if found is None else (*found, [])
        with open(path, "rb") as fh:
            check_zip_members(fh, str(path))  # a diagnosis never parses a directory of 10⁶ entries
        with zipfile.ZipFile(path) as archive:
            names = [n for n in archive.namelist() if n.endswith(".npy")]
            if HEADER_KEY + ".npy" in names:  # a btel model, damaged: the load error says so
                return None
            for name in names[:16]:
                with archive.open(name) as member:
                    found = matrix(member)
                if found is not None:
                    return (*found, [n.removesuffix(".npy") for n in names])
    except Exception:  # noqa: BLE001 - a diagnosis is best effort; the load error stands otherwise
        return None
    return None


def read_ground_truth(spec: str | None, option: str, *, n_queries: int, n_map: int, db: str | None,
                      queries: str, threshold: float | None = None) -> tuple[Any, dict[str, str]]:
    """``--ground-truth`` / ``--calibrate-truth`` read and checked against the query and map counts: the
    checked :class:`~btel.datasets.GroundTruth` and its ``{"source", "rule"}``; ``threshold`` (metres)
    applies to ``utm`` only."""
    from ..datasets.sources import resolve_ground_truth
    from ..evaluation.metrics import check_ground_truth
    from ..exceptions import InvalidParameterError
    from ._errors import InputError

    try:
        given, truth = resolve_ground_truth(spec, n_queries=n_queries, n_map=n_map, db=db, queries=queries,
                                            threshold=threshold if spec == "utm" else None)
    except InvalidParameterError as exc:
        raise InputError(f"{option}: {exc}") from None
    return check_ground_truth(given, n_queries, n_map, option=option), truth


def check_utm_options(ground_truth: str | None, calibrate_truth: str | None, db: str | None,
                      threshold: float | None) -> None:
    """``--ground-truth utm`` reads the map's image names from ``--db``; ``--positive-dist-threshold`` is
    its radius (and that of ``--calibrate-truth utm``)."""
    if (ground_truth == "utm" and db is None) or (threshold and "utm" not in (ground_truth, calibrate_truth)):
        raise click.UsageError("--ground-truth utm reads image names from --db (give it); "
                               "--positive-dist-threshold applies to it (and --calibrate-truth utm) only.")


def _check_calibration_flags(queries: str | None, truth: str | None, tolerance: int | None) -> None:
    if queries is None and (truth is not None or tolerance is not None):
        given = " and ".join(f for f, v in (("--calibrate-truth", truth), ("--calibrate-tolerance", tolerance))
                             if v is not None)
        raise click.UsageError(f"{given} {'applies' if ' and ' not in given else 'apply'} with --calibrate QUERIES "
                               "(the labelled queries it describes): give --calibrate too.")


def check_calibration_options(method: str, queries: str | None, truth: str | None,
                              tolerance: int | None) -> None:
    """``--calibrate-*`` only with ``--calibrate``, and only for a method whose ``fit`` takes calibration."""
    from ..evaluation.inputs import takes_calibration
    from ..methods.registry import make_method

    _check_calibration_flags(queries, truth, tolerance)
    if queries is not None and not takes_calibration(make_method(method)):
        raise click.UsageError(f"--calibrate chooses a method on labelled queries, which --method {method} does "
                               "not do. Use --method auto (or compare methods with `btel evaluate`).")


def check_evaluate_calibration(jobs: list[Any], db: str | None, queries: str | None, truth: str | None,
                               tolerance: int | None) -> None:
    """``btel evaluate``'s ``--calibrate-*``: with ``--calibrate``, which needs methods to fit (``--db``), one
    of them choosing on labelled queries. Raises a usage error before anything is read."""
    from ..evaluation.inputs import takes_calibration

    _check_calibration_flags(queries, truth, tolerance)
    if queries is None:
        return
    if db is None:
        raise click.UsageError("--calibrate chooses a method while fitting it on --db; saved --model files "
                               "are fitted already. Give --db and --methods auto.")
    if not any(takes_calibration(job.method) for job in jobs):
        raise click.UsageError(f"--calibrate chooses a method on labelled queries, which none of "
                               f"{', '.join(job.name for job in jobs)} does. Add auto to --methods.")


def calibration_input(db: str, queries: str, truth: str | None, n_map: int,
                      threshold: float | None = None) -> tuple[np.ndarray, object, dict[str, str]]:
    """``--calibrate QUERIES --calibrate-truth GT``: the labelled queries, their ground truth (true places
    as an int array, or the :class:`~btel.datasets.GroundTruth` of positives) and its description."""
    Q = _load_matrix(queries, "calibration queries")
    gt, said = read_ground_truth(truth, "--calibrate-truth", n_queries=Q.shape[0], n_map=n_map, db=db,
                                 queries=queries, threshold=threshold)
    return Q, (gt.query_places if gt.kind == "places" else gt), said


def calibrate_evaluation(jobs: list[Any], Q: np.ndarray, db: str, queries: str, truth: str | None,
                         tolerance: int | None, n_map: int, threshold: float | None) -> dict[str, Any]:
    """Give the jobs whose method takes calibration the labelled ``queries``; say on stderr which jobs
    fit without them and when evaluated queries (``Q``) are among them (an optimistic evaluation).
    The run's metadata of the calibration."""
    import numpy as np

    from ..evaluation.inputs import calibrate_jobs
    from ..exceptions import InvalidParameterError
    from ._errors import InputError

    Qc, given, said = calibration_input(db, queries, truth, n_map, threshold)
    if Qc.shape[1] != Q.shape[1]:
        raise InputError(f"--calibrate: the calibration queries have {Qc.shape[1]} dims but the map and queries "
                         f"{Q.shape[1]}; describe them with the same descriptor.")
    if Qc.shape[0] < 2:  # refused before any fit, as `btel train --calibrate` does
        raise InputError(f"--calibrate: calibration needs at least 2 labelled queries; {queries} holds "
                         f"{Qc.shape[0]}. Give more (a few hundred certify a difference of 0.10–0.15).")
    try:
        ignored = calibrate_jobs(jobs, (Qc, given), tolerance)
    except InvalidParameterError as exc:
        raise click.UsageError(str(exc)) from None
    calibrated = [job.name for job in jobs if job.name not in ignored]
    if ignored:
        click.echo(f"--calibrate: {', '.join(calibrated)} chosen on the {Qc.shape[0]} labelled queries; "
                   f"{', '.join(ignored)} fitted on the map alone (no calibration in their fit, or saved).",
                   err=True)
    rows = {np.ascontiguousarray(q, dtype=np.float32).tobytes() for q in Qc}
    shared = sum(np.ascontiguousarray(q, dtype=np.float32).tobytes() in rows for q in Q)
    if shared:
        click.echo(f"Warning: {shared} of the {Q.shape[0]} evaluated queries are calibration queries: the "
                   "evaluation is then optimistic; calibrate on a held-out part.", err=True)
    return {"queries": str(Path(queries).resolve()), "n_queries": int(Qc.shape[0]), "ground_truth": said,
            "tolerance": tolerance, "calibrated": calibrated, "not_calibrated": ignored}
