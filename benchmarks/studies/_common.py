"""The benchmarks' shared helpers (``benchmarks/_common.py``), importable from the studies' folder.

A study runs as ``python benchmarks/studies/<name>.py``, which puts this folder first on
``sys.path``; this module loads the parent's helpers under their own name and re-exports them, so
the results still go to ``benchmarks/results/``.
"""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

_PATH = Path(__file__).resolve().parents[1] / "_common.py"
_SPEC = importlib.util.spec_from_file_location("benchmarks_common", _PATH)
if _SPEC is None or _SPEC.loader is None:  # pragma: no cover - the file sits beside this folder
    raise ImportError(f"benchmarks helpers not found at {_PATH}")
_MODULE = sys.modules.setdefault("benchmarks_common", importlib.util.module_from_spec(_SPEC))
if not hasattr(_MODULE, "write_results"):
    _SPEC.loader.exec_module(_MODULE)
globals().update({name: value for name, value in vars(_MODULE).items() if not name.startswith("__")})
