"""Reading a run folder's ``metrics.json`` back (``btel evaluate --resume``, ``btel show``, ``--overwrite``).

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

__all__ = ["MAX_RUN_JSON_BYTES", "read_run_json", "read_run_payload"]

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
