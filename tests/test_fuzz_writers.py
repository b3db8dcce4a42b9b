"""A short seeded run of the writers' fuzz harness (``benchmarks/fuzz_writers.py``, issue 34).

Every case is a scenario: 2–4 writers of one target racing without ``--overwrite`` (``save``,
``btel train``, ``extract``, ``localize``, ``evaluate``), or one writer under a file size limit (a
full disk). Exactly one racer publishes and the others exit 2 saying the target exists; a failed
write ends in one error line; the target is whole or absent, no temporary or claim is left, and
every file has the umask's mode. The long run is ``python benchmarks/fuzz_writers.py --cases 2000
--seed 0`` (README, "Security").
"""

from __future__ import annotations

import importlib.util
import os
import sys
from pathlib import Path

import pytest

HARNESS_PATH = Path(__file__).resolve().parents[1] / "benchmarks" / "fuzz_writers.py"

pytestmark = pytest.mark.skipif(not hasattr(os, "fork"), reason="the harness forks its writers (POSIX)")


@pytest.fixture(scope="module")
def harness():
    spec = importlib.util.spec_from_file_location("fuzz_writers", HARNESS_PATH)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


def test_one_case_of_every_family_and_writer_passes(harness) -> None:
    summary = harness.run_cases(10, seed=3)
    assert set(summary["by_case"]) == {f"{f}/{w}" for f in harness.FAMILIES for w in harness.WRITERS}
    failures = [f"{c['family']}/{c['writer']} case {c['id']}: {c['outcome']} {c['problems']} {c['outputs']}"
                for c in summary["failed_cases"]]
    assert summary["failures"] == 0, "\n".join(failures)


def test_the_harness_catches_a_writer_that_replaces_what_it_should_keep(harness, monkeypatch) -> None:
    """With the publish step of old (a rename whatever is there), racing saves all 'succeed': a failure.
    The rename waits a second, so every racer has passed the early existence check before any publishes."""
    import time

    from btel import _claims

    def replace_later(tmp, path, *, overwrite):
        time.sleep(1.0)
        os.replace(tmp, path)

    monkeypatch.setattr(_claims, "publish", replace_later)
    summary = harness.run_cases(2, seed=0, writers=("save",), families=("race",))
    assert summary["failures"] == 2, summary
    assert all("writers published (want" in " ".join(c["problems"]) for c in summary["failed_cases"]), summary


def test_cases_are_reproducible(harness) -> None:
    cases = [harness.make_case(5, i) for i in range(40)]
    assert cases == [harness.make_case(5, i) for i in range(40)]
    assert len({(c["family"], c["writer"]) for c in cases}) == 10
