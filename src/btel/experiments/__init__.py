"""The paper's experiments on real Nordland frames, under one storage budget for every method.

Data: ``nordland64/{summer,winter}`` (3576 frame-aligned 64×32 frames, every 10th frame of the
videos). Descriptors: HOG (3780-D, the paper's Nordland setting) for every method except SeqSLAM, which works on its
own front end, 64×32 patch-normalised thumbnails (2048-D); both are extracted once and cached.
Ground truth is frame-aligned; tolerance is in frames (one frame ≈ 200 m here).

=================== =============================== ====================================================================
name                module                          what
=================== =============================== ====================================================================
``accuracy``        :mod:`.accuracy`                (a) recall vs tolerance t = 0…80 at ≤ 2 MB, N = 2000, both directions
``vs-n``            :mod:`.vs_n`                    (b) recall@10 vs N = 64 … 3576 at ≤ 0.5 MB
``vs-budget``       :mod:`.vs_budget`               (c) recall@10 vs budget 5 MB … 32 KB at N = 3576
``feature-ratio``   :mod:`.feature_ratio`           (d) BTE-C with c = 0.1 … 1 at r = 1
``regions``         :mod:`.regions`                 (e) BTEL with r = 1 … 20 at c = 0.1
``sequence-filter`` :mod:`.sequence_filter`         (f) the sequence filter, a = 5 and a = 20, at N = 3576 and 1 MB
``beyond``          :mod:`.beyond`                  the paper's variants against quantisation at the same bytes
``front-ends``      :mod:`.front_ends`              every front end (normalisation, delta, whitening) × method × read-out
``codes``           :mod:`.codes`                   output codes (btel-codes, every family and width) vs quantisers, 1 KB … 1 MB
``frontier``        :mod:`.frontier`                every method × 1 KB … 1 MB on routes and independent places; auto vs the oracle
=================== =============================== ====================================================================

Every row carries the method's bytes. A method that cannot fit a budget is reported as such (with
its minimum), never run over it; a fitted method whose bytes exceed its budget fails the run
(:class:`~btel.exceptions.BudgetExceededError`). Brute force is the unbudgeted upper reference.
``quick=True`` shrinks every experiment (first 300 frames, few points) for the tests.

Adding an experiment is one module with a function ``(data, out, quick) -> ExperimentRun`` (its
rows :class:`~btel.evaluation.records.EvaluationResult` records, its figure the run's ``plot``) and one line in
:data:`EXPERIMENTS`. The modules import :mod:`._common` only; nothing imports this package
back.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any, Callable

from ..exceptions import InvalidParameterError, OutputExistsError
from ..evaluation.runs import run_metadata
from ..evaluation.tables import describe_row
from ._common import QUICK_FRAMES, ExperimentRun, NordlandData, default_nordland_root, write_results
from .accuracy import exp_accuracy
from .beyond import exp_beyond
from .codes import exp_codes
from .feature_ratio import exp_feature_ratio
from .front_ends import exp_front_ends
from .frontier import exp_frontier
from .regions import exp_regions
from .sequence_filter import exp_sequence_filter
from .vs_budget import exp_vs_budget
from .vs_n import exp_vs_n

__all__ = ["EXPERIMENTS", "PARALLEL", "RESUMABLE", "NordlandData", "ExperimentRun", "run_experiment", "check_request", "default_nordland_root", "describe_row"]

EXPERIMENTS: dict[str, Callable[[NordlandData, Path, bool], ExperimentRun]] = {
    "accuracy": exp_accuracy,
    "vs-n": exp_vs_n,
    "vs-budget": exp_vs_budget,
    "feature-ratio": exp_feature_ratio,
    "regions": exp_regions,
    "sequence-filter": exp_sequence_filter,
    "beyond": exp_beyond,
    "front-ends": exp_front_ends,
    "codes": exp_codes,
    "frontier": exp_frontier,
}


#: Experiments that choose every method's front end themselves (they refuse a global override).
SELF_CONTAINED = ("beyond", "front-ends", "codes", "frontier")
#: Experiments whose independent parts can run in several processes (their function takes ``jobs``).
PARALLEL = ("frontier",)
#: Experiments that journal their rows as they finish and can take up an interrupted run (``resume``).
RESUMABLE = ("frontier",)


def run_experiment(name: str, *, data_root: str | Path | None = None, out_dir: str | Path = "runs/experiments",
                   cache_dir: str | Path | None = None, quick: bool = False, progress: bool = True,
                   command: str | None = None, front_end: dict[str, Any] | None = None,
                   jobs: int = 1, resume: bool = False, overwrite: bool = False) -> ExperimentRun:
    """Run one experiment and write ``<out_dir>/<name>/results.{csv,json}`` and its plot(s).

    ``front_end`` (e.g. ``{"delta": 10}``) is given to every method of the paper's experiments (a)–(f)
    and the results go to ``<out_dir>/<name>-delta-10/``; the experiments that compare front ends
    or variants themselves (beyond, front-ends, codes) refuse it. ``jobs`` > 1 runs the independent
    parts of an experiment of :data:`PARALLEL` in that many processes (the others refuse it);
    ``resume`` takes up an interrupted run of an experiment of :data:`RESUMABLE` from its journal.
    An earlier run's results in ``<out_dir>/<name>/`` are replaced only with ``overwrite``
    (:func:`check_output`).

    Raises
    ------
    InvalidParameterError
        Unknown experiment name, or an option it does not take (:func:`check_request`).
    OutputExistsError
        ``<out_dir>/<name>/`` holds an earlier run and neither ``overwrite`` nor ``resume`` was given.
    DataNotFoundError
        Missing Nordland folders.
    BudgetExceededError
        A method stored more bytes than its budget.
    """
    front_end = {k: v for k, v in (front_end or {}).items() if v is not None} or None
    check_request(name, front_end=front_end, jobs=jobs, resume=resume)
    root = Path(data_root) if data_root else default_nordland_root()
    out = output_folder(name, out_dir, front_end)
    check_output(out, overwrite=overwrite, resume=resume)
    data = NordlandData(root, Path(cache_dir) if cache_dir else Path(out_dir) / "cache", progress=progress,
                        max_frames=QUICK_FRAMES if quick else None, front_end=front_end)
    start = time.perf_counter()
    options = {**({"jobs": jobs} if name in PARALLEL else {}), **({"resume": resume} if name in RESUMABLE else {})}
    run = EXPERIMENTS[name](data, out, quick, **options)
    meta = {**run_metadata(command or f"btel experiment {name}{' --quick' if quick else ''}"), "experiment": name,
            "quick": quick, "jobs": jobs, "resume": resume, "data": str(root.resolve()),
            "descriptor": _descriptors(run),
            "front_end": front_end or "each method's default (rows L2-normalised; SeqSLAM none)",
            "seconds": time.perf_counter() - start}
    write_results(run, out, meta)
    return run


def _descriptors(run: ExperimentRun) -> str:
    """What the run's rows describe places by: the rows' own ``descriptor`` cells where they have them
    (the experiments on several data sets), else the paper's Nordland descriptors."""
    named = list(dict.fromkeys(str(d) for d in (r.to_row().get("descriptor") for r in run.rows) if d))
    return "per row: " + ", ".join(named) if named else "HOG 3780-D (SeqSLAM: 64×32 patch-normalised, 2048-D)"


def output_folder(name: str, out_dir: str | Path, front_end: dict[str, Any] | None = None) -> Path:
    """Where experiment ``name`` writes: ``<out_dir>/<name>[-delta-W]``."""
    front_end = {k: v for k, v in (front_end or {}).items() if v is not None}
    return Path(out_dir) / (name + "".join(f"-{k}-{v}" for k, v in sorted(front_end.items())))


def check_output(out: Path, *, overwrite: bool = False, resume: bool = False) -> None:
    """Refuse to replace an earlier run's results (``results.json``, or a frontier journal) in ``out``
    unless ``overwrite``; ``resume`` takes up a journal instead. Touches nothing.

    Raises
    ------
    OutputExistsError
        ``out`` is a file, or holds ``results.json`` or ``rows.jsonl`` and neither flag is given.
    """
    if out.exists() and not out.is_dir():
        raise OutputExistsError(f"{str(out)!r} exists and is a file; give another --out folder.")
    if overwrite or resume:
        return
    earlier = [f for f in ("results.json", "rows.jsonl") if (out / f).exists()]
    if earlier:
        journal = " (an interrupted frontier: --resume takes it up)" if earlier == ["rows.jsonl"] else ""
        raise OutputExistsError(f"{str(out)!r} holds an earlier run ({', '.join(earlier)}){journal}; give "
                                "--overwrite (overwrite=True) to replace it, or another --out folder.")


def check_request(name: str, *, front_end: dict[str, Any] | None = None, jobs: int = 1, resume: bool = False) -> None:
    """Refuse an unknown experiment, or an option it does not take, before anything runs or prints.

    Raises
    ------
    InvalidParameterError
        Unknown name; ``front_end`` for an experiment that sets front ends itself; ``jobs`` that is
        not a whole number ≥ 1, or > 1 or ``resume`` for an experiment that cannot use it.
    """
    if name not in EXPERIMENTS:
        raise InvalidParameterError(f"unknown experiment {name!r}; choose from {', '.join(EXPERIMENTS)} or 'all'.")
    if front_end and name in SELF_CONTAINED:
        raise InvalidParameterError(f"experiment {name!r} sets each method's front end itself; run it without "
                                    "--delta (the paper's experiments (a)–(f) take it).")
    if isinstance(jobs, bool) or not isinstance(jobs, int) or jobs < 1:
        raise InvalidParameterError(f"jobs must be a whole number ≥ 1, got {jobs!r}.")
    if jobs > 1 and name not in PARALLEL:
        raise InvalidParameterError(f"experiment {name!r} runs in one process; --jobs applies to "
                                    f"{', '.join(PARALLEL)} only: run it without --jobs.")
    if resume and name not in RESUMABLE:
        raise InvalidParameterError(f"experiment {name!r} keeps no journal to resume from; --resume applies to "
                                    f"{', '.join(RESUMABLE)} only: run it without --resume.")
