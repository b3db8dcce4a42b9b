"""Reading a run folder's ``metrics.json`` back (``btel evaluate --resume``, ``btel show``, ``--overwrite``),
and what it says in words (:func:`describe_run`).

A run folder is user-writable: its ``metrics.json`` may have been edited, damaged or replaced by a FIFO,
a huge file or JSON nested past the parser's depth. Every reader goes through :func:`read_run_payload`,
so each of those is one error naming the file and the fix, never a traceback or a hang.
"""

from __future__ import annotations

import json
import os
from typing import Any

from ..core.limits import open_regular
from ..exceptions import InvalidParameterError

__all__ = ["MAX_RUN_JSON_BYTES", "describe_run", "read_run_json", "read_run_payload"]

#: Largest run JSON file read (64 MiB, as the frontier's journal; a run of 100 rows is well under 1 MiB:
#: predictions are in the CSV files, not here).
MAX_RUN_JSON_BYTES = 64 << 20

#: The fix a message offers when the caller names none.
_DEFAULT_FIX = "run `btel evaluate` again (into a new --out folder) to write the run anew"


def read_run_json(path: str | os.PathLike, fix: str = _DEFAULT_FIX) -> Any:
    """The JSON value of the run file ``path``: a regular UTF-8 file of at most :data:`MAX_RUN_JSON_BYTES`.

    Raises
    ------
    DataNotFoundError
        ``path`` cannot be opened, or is not a regular file (a FIFO is refused without waiting on it).
    InvalidParameterError
        Larger than the cap, not UTF-8, not JSON, or nested deeper than the parser goes; the message
        names ``path`` and ends with ``fix``.
    """
    with open_regular(path) as fh:
        data = fh.read(MAX_RUN_JSON_BYTES + 1)  # one byte over: a file growing past its stat is caught too
    if len(data) > MAX_RUN_JSON_BYTES:
        raise InvalidParameterError(f"{str(path)!r} holds more than {MAX_RUN_JSON_BYTES >> 20} MiB, far more than "
                                    f"btel writes in a run's metrics: it is not one; {fix}.")
    try:
        return json.loads(data.decode("utf-8"))
    except UnicodeDecodeError as exc:
        why = f"not UTF-8 text ({exc.reason} at byte {exc.start})"
    except RecursionError:  # json recurses once per level: '[' * 100000 exhausts the stack
        why = "JSON nested deeper than btel reads (btel writes a few levels)"
    except ValueError as exc:  # JSONDecodeError, and int() of a number with too many digits
        why = f"not JSON ({exc})"
    raise InvalidParameterError(f"{str(path)!r} is not a btel run's metrics: {why}; {fix}.")


def read_run_payload(path: str | os.PathLike, fix: str = _DEFAULT_FIX) -> tuple[dict[str, Any], list[Any]]:
    """``(run, results)`` of the ``metrics.json`` at ``path``: its ``"run"`` object and ``"results"`` list (rows
    unchecked; :meth:`~btel.evaluation.records.EvaluationResult.from_dict` checks each).

    Raises
    ------
    DataNotFoundError, InvalidParameterError
        As :func:`read_run_json`; also an object without ``"run"`` (an object) and ``"results"`` (a list).
    """
    payload = read_run_json(path, fix)
    run = payload.get("run") if isinstance(payload, dict) else None
    results = payload.get("results") if isinstance(payload, dict) else None
    if not isinstance(run, dict) or not isinstance(results, list):
        raise InvalidParameterError(f"{str(path)!r} is not a btel run's metrics: it must be a JSON object with a "
                                    f"\"run\" object and a \"results\" list; {fix}.")
    return run, results


def _text(value: Any, limit: int = 300) -> str:
    """A recorded value as text of bounded length (the file is the user's: it may hold anything)."""
    text = value if isinstance(value, str) else json.dumps(value, ensure_ascii=False, default=str)
    return text if len(text) <= limit else text[:limit] + " …"


def describe_run(path: str | os.PathLike, width: int = 0) -> str:
    """What the run folder ``path`` (its ``metrics.json``) records, as ``btel show`` prints it: the command
    and where it ran, when, which btel and libraries, the machine and threads, every input with its
    fingerprint, the ground truth, the results table and what each row's fit chose.

    Raises
    ------
    DataNotFoundError, InvalidParameterError
        As :func:`read_run_payload`, and a row :meth:`~btel.evaluation.records.EvaluationResult.from_dict`
        refuses.
    """
    from .records import EvaluationResult
    from .tables import format_table

    metrics = os.path.join(os.fspath(path), "metrics.json")
    run, rows = read_run_payload(metrics, "run `btel evaluate` again to write the run anew")
    results = []
    for i, row in enumerate(rows):
        try:
            results.append(EvaluationResult.from_dict(row))
        except InvalidParameterError as exc:
            raise InvalidParameterError(f"{metrics}: results[{i}] is {exc} The file was edited or damaged: run "
                                        "`btel evaluate` again to write the run anew.") from None
    done = sum(r.ok for r in results)
    extra = run.get("extra") if isinstance(run.get("extra"), dict) else {}
    resumable = extra.get("data") != "synthetic_route"  # a demo is run again, not resumed
    state = "complete" if run.get("complete") is True else (
        "incomplete (interrupted" + (": `btel evaluate --resume` goes on)" if resumable else ")"))
    lines = [f"run: {os.fspath(path)}, {state}; {done} of {len(results)} rows measured",
             f"command: {_text(run.get('command'))}" + (f"  (in {_text(run['cwd'])})" if run.get("cwd") else "")]
    when = [f"started {_text(run.get('date_utc'))}"]
    if run.get("updated_utc"):
        when.append(f"last written {_text(run['updated_utc'])} ({_text(run.get('seconds'))} s)")
    lines.append(", ".join(when))
    versions = run.get("versions") if isinstance(run.get("versions"), dict) else {}
    commit = run.get("btel_commit")
    lines.append("software: " + ", ".join(f"{k} {_text(v, 40)}" for k, v in versions.items() if v)
                 + (f"; btel source commit {_text(commit, 64)}" if commit else ""))
    threads = run.get("threads") if isinstance(run.get("threads"), dict) else {}
    libraries = threads.get("libraries")
    pools = [f"{_text(lib.get('internal_api'), 20)} {_text(lib.get('num_threads'), 8)}"
             for lib in (libraries if isinstance(libraries, list) else []) if isinstance(lib, dict)]
    loads = [f"{load[0]:.2f} {when}" for key, when in (("load_average", "at the start"),
                                                       ("load_average_updated", "at the last write"))
             if isinstance(load := run.get(key), list) and load and isinstance(load[0], (int, float))]
    lines.append(f"machine: {_text(run.get('cpu') or run.get('machine'))}, {_text(run.get('cpu_count'))} cores"
                 + (f"; threads: {', '.join(pools)}" if pools else "")
                 + (f"; load average {', '.join(loads)}" if loads else ""))
    inputs = extra.get("inputs") if isinstance(extra.get("inputs"), dict) else {}
    for option, entry in inputs.items():
        for item in entry if isinstance(entry, list) else [entry]:
            if isinstance(item, dict):
                size = item.get("bytes")
                size = f"{size:,d}" if isinstance(size, int) else _text(size, 20)
                lines.append(f"input {_text(option, 40)}: {_text(item.get('path'))} (sha256 "
                             f"{_text(item.get('sha256'), 64)[:16]}…, {size} B)")
    if not inputs and extra.get("data"):
        lines.append(f"data: {_text(extra['data'])} (generated by btel: no input files)")
    truth = extra.get("ground_truth") if isinstance(extra.get("ground_truth"), dict) else None
    if truth:
        lines.append(f"ground truth: {_text(truth.get('rule'))} ({_text(truth.get('source'))})")
    lines += ["", format_table(results, width)]
    chosen = [f"  {r.name}: " + ", ".join(f"{k}={_text(v, 60)}" for k, v in r.chosen_at_fit.items())
              for r in results if r.chosen_at_fit]
    chosen += [f"  {r.name}: {_text(r.choice.get('method'), 40)} {_text(r.choice.get('params'), 120)} — "
               f"{_text(r.choice.get('reason'), 400)}" for r in results if r.choice]
    if chosen:
        lines += ["chosen at fit (parameters given as None or 'auto', and what auto chose):", *chosen]
    return "\n".join(lines)
