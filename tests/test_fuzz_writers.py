"""A short seeded run of the writers' fuzz harness (``benchmarks/fuzz_writers.py``, issue 34).

Every case is a scenario: 2–4 writers of one target racing without ``--overwrite`` (``save``,
``btel train``, ``extract``, ``localize``, ``evaluate``), or one writer under a file size limit (a
full disk). Exactly one racer publishes and the others exit 2 saying the target exists; a failed
write ends in one error line; the target is whole or absent, no temporary or claim is left, and
every file has the umask's mode. The long run is ``python benchmarks/fuzz_writers.py --cases 2000
--seed 0`` (README, "Security").

The harness forks its writers, so it runs in a fresh interpreter here: a test process that has
already started thread pools (OpenMP, BLAS) cannot fork safely.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

HARNESS_PATH = Path(__file__).resolve().parents[1] / "benchmarks" / "fuzz_writers.py"

pytestmark = pytest.mark.skipif(not hasattr(os, "fork"), reason="the harness forks its writers (POSIX)")


def _run(code: str, tmp_path: Path) -> dict:
    """Run ``code`` (with the harness imported as ``fw``) in a fresh interpreter; it prints a summary."""
    script = (f"import json, sys\nsys.path.insert(0, {str(HARNESS_PATH.parent)!r})\n"
              "import fuzz_writers as fw\n" + code)
    env = {**os.environ, "OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1"}
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=900,
                          cwd=tmp_path, env=env)
    assert proc.returncode == 0, proc.stderr[-2000:]
    return json.loads(proc.stdout.strip().splitlines()[-1])


def test_one_case_of_every_family_and_writer_passes(tmp_path: Path) -> None:
    summary = _run("print(json.dumps(fw.run_cases(10, seed=3)))", tmp_path)
    assert set(summary["by_case"]) == {f"{f}/{w}" for f in ("race", "fault")
                                       for w in ("save", "train", "extract", "localize", "evaluate")}
    failures = [f"{c['family']}/{c['writer']} case {c['id']}: {c['outcome']} {c['problems']} {c['outputs']}"
                for c in summary["failed_cases"]]
    assert summary["failures"] == 0, "\n".join(failures)


def test_the_harness_catches_a_writer_that_replaces_what_it_should_keep(tmp_path: Path) -> None:
    """With the publish step of old (a rename whatever is there), racing saves all 'succeed': a failure.
    The rename waits a second, so every racer has passed the early existence check before any publishes."""
    summary = _run(
        "import os, time\nfrom btel.core import claims as _claims\n"
        "def replace_later(tmp, path, *, overwrite):\n    time.sleep(1.0)\n    os.replace(tmp, path)\n"
        "_claims.publish = replace_later\n"
        "print(json.dumps(fw.run_cases(2, seed=0, writers=('save',), families=('race',))))", tmp_path)
    assert summary["failures"] == 2, summary
    assert all("writers published (want" in " ".join(c["problems"]) for c in summary["failed_cases"]), summary


def test_cases_are_reproducible(tmp_path: Path) -> None:
    result = _run("print(json.dumps([[fw.make_case(5, i) for i in range(40)] for _ in range(2)]))", tmp_path)
    first, again = result
    assert first == again and len({(c["family"], c["writer"]) for c in first}) == 10
