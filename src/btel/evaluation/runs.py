"""Run folders: the files one evaluation writes, and where and how the run was made.

:func:`write_run` turns :class:`~btel.evaluation.records.EvaluationResult` objects into a run folder —
``metrics.json``, ``metrics.csv``, ``predictions_<method>.csv`` and the plots;
:func:`run_metadata` records the command line, library versions, platform and date (the
experiments' ``results.json`` carries it too); :func:`recompute_recall_from_csv` checks a folder
by recomputing recall from the predictions it holds.
"""

from __future__ import annotations

import csv
import datetime as _dt
import importlib.metadata
import json
import os
import platform
import re
import shlex
import sys
import time
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..core.modelfile import jsonable
from ..core.threads import load_average  # a run records the machine's load (tests patch it here)
from .metrics import DEFAULT_TOLERANCES, recall_at_tolerance
from .records import EvaluationResult
from .tables import RUN_COLUMNS, calibration_markdown, metrics_csv_text, predictions_csv_text
from ..exceptions import DataNotFoundError, InvalidParameterError, OutputExistsError

__all__ = ["RunReport", "RunWriter", "check_run_folder", "run_metadata", "write_run",
           "recompute_recall_from_csv", "safe_file_name"]


@dataclass
class RunReport:
    """The files :func:`write_run` wrote.

    Attributes
    ----------
    out_dir : Path
    metrics_json, metrics_csv : Path
    predictions : dict of str to Path
        Method name → its ``predictions_<name>.csv``.
    plots : list of Path
        PNG files.
    calibration : Path or None
        ``calibration.md``, the calibration tables of the rows that chose on labelled queries.
    """

    out_dir: Path
    metrics_json: Path
    metrics_csv: Path
    predictions: dict[str, Path]
    plots: list[Path]
    calibration: Path | None = None


def _package_version(*names: str) -> str | None:
    for n in names:
        try:
            return importlib.metadata.version(n)
        except importlib.metadata.PackageNotFoundError:
            continue
    return None


def _source_commit() -> str | None:
    """The git commit of btel's source when it runs from a git checkout (``pip install -e``), else None."""
    import subprocess

    root = Path(__file__).resolve().parents[3]
    if not (root / ".git").exists():
        return None
    try:
        done = subprocess.run(["git", "-C", str(root), "rev-parse", "HEAD"], capture_output=True, text=True,
                              timeout=5, check=False)
    except (OSError, subprocess.SubprocessError):  # no git on the machine, or it hung
        return None
    commit = done.stdout.strip()
    return commit if done.returncode == 0 and re.fullmatch(r"[0-9a-f]{40,64}", commit) else None


def _cpu_model() -> str | None:
    """The processor's model name (Linux: /proc/cpuinfo), or None."""
    try:
        with open("/proc/cpuinfo", encoding="utf-8", errors="replace") as fh:
            for line in fh.read(1 << 16).splitlines():
                if line.startswith("model name") and ":" in line:
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or None


def run_metadata(command: str | Sequence[str] | None = None) -> dict[str, Any]:
    """Where and how a run was made: command line and working directory, btel's version and source
    commit (a git checkout), library versions, platform, processor, thread pools, UTC date."""
    from ..core.threads import thread_settings

    if command is None:
        command = shlex.join(sys.argv)
    elif not isinstance(command, str):
        command = shlex.join(str(c) for c in command)
    return {
        "command": command,
        "cwd": os.getcwd(),
        "date_utc": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
        "btel_commit": _source_commit(),
        "versions": {
            "btel": _package_version("btel"),
            "python": platform.python_version(),
            "numpy": np.__version__,
            "scipy": _package_version("scipy"),
            "scikit-learn": _package_version("scikit-learn"),
            "faiss": _package_version("faiss-cpu", "faiss", "faiss-gpu"),
            "matplotlib": _package_version("matplotlib"),
        },
        "platform": platform.platform(),
        "machine": platform.machine(),
        "cpu": _cpu_model(),
        "cpu_count": os.cpu_count(),
        "threads": thread_settings(),
        "load_average": load_average(),
    }


def safe_file_name(name: str) -> str:
    """A row name as a file-name part: letters, digits, ``.``, ``_`` and ``-`` only, every other run of
    characters one ``-`` (``"bruteforce shrink"`` → ``bruteforce-shrink``, ``"pq@100KB"`` →
    ``pq-100KB``)."""
    return re.sub(r"[^A-Za-z0-9._-]+", "-", name).strip("._-") or "method"


#: Files a run folder may hold; with ``overwrite=True`` these (and only these) are removed first.
_RUN_FILE_PATTERNS = ("metrics.json", "metrics.csv", "predictions_*.csv", "gallery_*.png", "recall_vs_*.png", "recall_at_k.png",
                      "precision_recall.png", ".metrics.*.tmp", "calibration.md")


_LOCK_NAME = ".btel-run.lock"


def _occupants(out_dir: Path) -> list[Path]:
    """Entries of a run folder other than a dead run's claim and temporaries."""
    from ..core.claims import _owner, pid_alive

    out = []
    for entry in out_dir.iterdir():
        if entry.name == _LOCK_NAME:
            owner = _owner(entry)
            if owner is not None and owner != os.getpid() and pid_alive(owner):
                raise OutputExistsError(
                    f"another btel run (process {owner}) is writing to {str(out_dir)!r}; wait for it to finish "
                    "or choose another --out folder.")
            continue
        if entry.name.startswith(".") and entry.name.endswith(".tmp") and _temp_is_dead(entry.name):
            continue
        out.append(entry)
    return out


def _temp_is_dead(name: str) -> bool:
    from ..core.claims import pid_alive

    match = re.match(r"\.[^/]+\.(\d{1,10})\.[^/]*\.tmp$", name)
    return match is None or not pid_alive(int(match.group(1)))


def check_run_folder(out_dir: str | os.PathLike, overwrite: bool = False) -> None:
    """Raise now (before any work) if ``out_dir`` cannot become a run folder; touches nothing.

    Raises
    ------
    OutputExistsError
        ``out_dir`` is a file, or a non-empty folder and ``overwrite`` is False, or another live
        run is writing to it (even with ``overwrite``); a ``FileExistsError``.
    """
    out_dir = Path(out_dir)
    if out_dir.exists() and not out_dir.is_dir():
        raise OutputExistsError(f"run folder {str(out_dir)!r} exists and is a file; choose another --out "
                                "folder.")
    occupants = _occupants(out_dir) if out_dir.is_dir() else []
    if occupants and not overwrite:
        raise OutputExistsError(
            f"run folder {str(out_dir)!r} already exists and is not empty; choose a new folder "
            "or pass overwrite=True (CLI: --overwrite) to replace its results."
        )
    if occupants and _previous_run_files(out_dir) is None:
        named = sorted(p.name for pattern in _RUN_FILE_PATTERNS for p in out_dir.glob(pattern))
        if named:  # a user's files that merely look like a run's: never removed
            raise OutputExistsError(
                f"{str(out_dir)!r} holds {', '.join(named[:3])}{' …' * (len(named) > 3)} but no btel run (its "
                "metrics.json is missing or not a btel run's); --overwrite replaces a btel run's files only. "
                "Choose another --out folder.")


def _previous_run_files(out_dir: Path) -> list[Path] | None:
    """The files the btel run recorded in ``out_dir/metrics.json`` wrote (None: no btel run there)."""
    from .runfile import read_run_payload
    from ..exceptions import BTELError

    try:  # bounded and refusing FIFOs: a hostile metrics.json makes the folder "no btel run", not a hang
        names = [safe_file_name(str(r["name"])) for r in read_run_payload(out_dir / "metrics.json")[1]]
    except (OSError, BTELError, KeyError, TypeError):
        return None
    fixed = [p for pattern in _RUN_FILE_PATTERNS if "*" not in pattern or pattern.startswith(("recall_vs_", "."))
             for p in out_dir.glob(pattern)]
    return fixed + [out_dir / f"{kind}_{name}.{ext}" for name in names
                    for kind, ext in (("predictions", "csv"), ("gallery", "png"))]


def _prepare_out_dir(out_dir: Path, overwrite: bool) -> Path:
    """Check, then atomically claim the folder (a lock file) and check again under the claim:
    two runs started at once into one folder cannot both pass. Returns the lock file."""
    from ..core.claims import claim, release

    check_run_folder(out_dir, overwrite)
    out_dir.mkdir(parents=True, exist_ok=True)
    lock = claim(out_dir, _LOCK_NAME)
    try:
        # Under the claim every temporary here is a dead writer's.
        for pattern in (".metrics.*.tmp", ".predictions_*.tmp"):
            for stale in out_dir.glob(pattern):
                stale.unlink()
        occupants = _occupants(out_dir)
        if occupants and not overwrite:
            raise OutputExistsError(
                f"run folder {str(out_dir)!r} was filled by another run meanwhile; choose a new folder "
                "or pass overwrite=True (CLI: --overwrite).")
        if occupants:
            # Remove the previous run's files so no stale predictions_<old method>.csv is left behind;
            # anything else the user put there is kept (a predictions_mine.csv the run did not write too).
            for old in _previous_run_files(out_dir) or []:
                old.unlink(missing_ok=True)
    except BaseException:
        release(lock)
        raise
    return lock


def _atomic_write_text(path: Path, text: str) -> None:
    """Write ``text`` to ``path`` through a uniquely named temporary and a rename: a reader (or a
    crash, or a full disk) sees the old file or the new one, never half of one, and a failed
    write leaves no temporary behind."""
    from ..core.claims import atomic_output, write_error

    try:
        with atomic_output(path, text=True, suffix=".tmp") as fh:
            fh.write(text)
    except OSError as exc:
        raise write_error(exc.errno, f"{exc}; the rows finished before are kept in the run folder") from None


class RunWriter:
    """A run folder written as an evaluation goes: metrics after every method, plots at the end.

    Creating the writer checks the folder at once (before anything is fitted): an existing
    non-empty folder is refused unless ``overwrite``. :meth:`write` rewrites ``metrics.json`` and
    ``metrics.csv`` atomically with every row so far (rows that did not run included, with their
    status and reason) and writes the new rows' predictions; ``metrics.json`` says
    ``"complete": false`` until :meth:`finish` draws the plots (and writes ``calibration.md`` when a
    row chose on labelled queries) and marks it complete. A crash or
    Ctrl-C between methods therefore leaves every finished method on disk.

    Parameters
    ----------
    out_dir : path
    command : str or sequence of str, optional
        Command line to record; default ``sys.argv``.
    extra : mapping, optional
        More run metadata (data set, budget, …), JSON-safe.
    overwrite : bool, default False
        Replace the run files of an existing non-empty folder (only run files are removed).

    Raises
    ------
    OutputExistsError
        ``out_dir`` exists, is not empty, and ``overwrite`` is False; or it is a file (a ``FileExistsError``).
    """

    def __init__(self, out_dir: str | os.PathLike, *, command: str | Sequence[str] | None = None,
                 extra: Mapping[str, Any] | None = None, overwrite: bool = False) -> None:
        self.out_dir = Path(out_dir)
        self._lock: Path | None = _prepare_out_dir(self.out_dir, overwrite)
        self.meta = run_metadata(command)
        self._started = time.monotonic()
        if extra:
            self.meta["extra"] = jsonable(dict(extra))
        self.metrics_json = self.out_dir / "metrics.json"
        self.metrics_csv = self.out_dir / "metrics.csv"
        self.predictions: dict[str, Path] = {}
        self.plots: list[Path] = []
        self.query_names: Sequence[str] | None = None
        self.db_names: Sequence[str] | None = None

    def write(self, results: Sequence[EvaluationResult], *, complete: bool = False) -> None:
        """Write the metrics of every row so far, and the predictions of rows not written yet."""
        results = list(results)
        safe = [safe_file_name(r.name) for r in results]
        if len(set(safe)) != len(safe):
            raise InvalidParameterError(
                f"method names {[r.name for r in results]} are not distinct once made file-safe ({safe}); "
                "give each evaluate(...) call its own name=."
            )
        now = _dt.datetime.now(_dt.timezone.utc)
        timing = {"updated_utc": now.isoformat(timespec="seconds"), "load_average_updated": load_average(),
                  "seconds": round(time.monotonic() - self._started, 3)}  # this writer's; a resumed run's own part
        payload = {"run": {**self.meta, **timing, "complete": bool(complete)}, "columns": RUN_COLUMNS,
                   "results": [r.to_dict() for r in results]}
        _atomic_write_text(self.metrics_json, json.dumps(payload, indent=2, allow_nan=False, default=repr) + "\n")
        _atomic_write_text(self.metrics_csv, metrics_csv_text(results))
        for r, stem in zip(results, safe):
            if not r.ok or r.name in self.predictions:
                continue
            path = self.out_dir / f"predictions_{stem}.csv"
            _atomic_write_text(path, predictions_csv_text(r, self.query_names, self.db_names))
            self.predictions[r.name] = path

    def close(self) -> None:
        """Release the claim on the run folder (done by :meth:`finish`; a crashed run's claim is
        released when its process is gone)."""
        from ..core.claims import release

        release(self._lock)
        self._lock = None

    def finish(self, results: Sequence[EvaluationResult], *, plots: bool = True, title: str | None = None,
               tolerance_unit: str = "frames") -> "RunReport":
        """Write the final metrics (``"complete": true``) and the plots; return what was written.

        ``tolerance_unit``: ``"frames"`` (queries along a route) or ``"map places"`` (independent
        queries), for the plots' axis labels (:func:`btel.evaluation.plots.plot_run`)."""
        results = list(results)
        calibration = None
        try:
            self.write(results, complete=True)
            text = calibration_markdown(results, title)
            if text:
                calibration = self.out_dir / "calibration.md"
                _atomic_write_text(calibration, text)
            measured = [r for r in results if r.ok]
            if plots and measured:
                from . import plots as _plots

                self.plots = _plots.plot_run(measured, self.out_dir, title=title,
                                             not_run=[r for r in results if not r.ok], tolerance_unit=tolerance_unit)
        finally:
            self.close()
        return RunReport(self.out_dir, self.metrics_json, self.metrics_csv, dict(self.predictions), list(self.plots),
                         calibration)


def write_run(
    results: Sequence[EvaluationResult],
    out_dir: str | os.PathLike,
    *,
    command: str | Sequence[str] | None = None,
    extra: Mapping[str, Any] | None = None,
    overwrite: bool = False,
    plots: bool = True,
    title: str | None = None,
) -> RunReport:
    """Write a run folder at once: metrics, per-method predictions and plots (see :class:`RunWriter`).

    Files:

    - ``metrics.json`` — ``{"run": run_metadata(command) + extra + complete, "results": [r.to_dict(), …]}``;
    - ``metrics.csv`` — one row per method: method, status, reference, uses_query_sequence, budget,
      n_map, n_queries, nbytes, fit_time_s, query_time_s_per_query, ``recall@t`` for every
      tolerance, ``R@K`` for every K (blank where a row has none), reason;
    - ``predictions_<method>.csv`` — columns ``query,prediction``, ``true`` when the ground truth
      has one true place per query, and ``rank_1…rank_K`` (rows that ran only);
    - ``recall_vs_tolerance.png`` (frame-aligned ground truth) or ``recall_at_k.png`` (explicit
      positives), and ``recall_vs_storage.png`` when storage is known;
    - ``calibration.md`` when a row chose its method on labelled queries (auto with ``calibration``):
      its calibration table (:func:`~btel.evaluation.tables.calibration_markdown`).

    Parameters
    ----------
    results : sequence of EvaluationResult
        Method names must be distinct (they name the files).
    out_dir : path
        Created if missing.
    command : str or sequence of str, optional
        Command line to record; default ``sys.argv``.
    extra : mapping, optional
        More run metadata (data set, budget, …), JSON-safe.
    overwrite : bool, default False
        Replace the results in an existing non-empty folder (only run files are removed).
    plots : bool, default True
        Also draw the PNG plots.
    title : str, optional
        Plot title (data set, budget, ground truth).

    Returns
    -------
    RunReport

    Raises
    ------
    OutputExistsError
        ``out_dir`` exists, is not empty, and ``overwrite`` is False (a ``FileExistsError``).
    InvalidParameterError
        No results, or two results whose names give the same file name.
    """
    results = list(results)
    if not results:
        raise InvalidParameterError("write_run needs at least one EvaluationResult.")
    safe = [safe_file_name(r.name) for r in results]
    if len(set(safe)) != len(safe):
        raise InvalidParameterError(
            f"method names {[r.name for r in results]} are not distinct once made file-safe ({safe}); "
            "give each evaluate(...) call its own name=."
        )
    writer = RunWriter(out_dir, command=command, extra=extra, overwrite=overwrite)
    return writer.finish(results, plots=plots, title=title)


def recompute_recall_from_csv(
    predictions_csv: str | os.PathLike, tolerances: Iterable[int] = DEFAULT_TOLERANCES
) -> dict[int, float]:
    """Recall at each tolerance recomputed from a ``predictions_<method>.csv`` file.

    Uses the ``true`` column when present, else frame alignment (true place = query index).
    """
    path = Path(predictions_csv)
    if not path.is_file():
        raise DataNotFoundError(f"predictions file {str(path)!r} does not exist.")
    with open(path, newline="", encoding="utf-8") as fh:
        reader = csv.DictReader(fh)
        if reader.fieldnames is None or not {"query", "prediction"} <= set(reader.fieldnames):
            raise DataNotFoundError(
                f"{str(path)!r} is not a predictions file (needs columns query,prediction; got {reader.fieldnames})."
            )
        rows = list(reader)
    query = np.array([int(r["query"]) for r in rows], dtype=np.int64)
    pred = np.array([int(r["prediction"]) for r in rows], dtype=np.int64)
    true = np.array([int(r["true"]) for r in rows], dtype=np.int64) if "true" in reader.fieldnames else query
    return recall_at_tolerance(pred, true, tolerances)
