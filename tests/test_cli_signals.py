"""btel.cli._signals: Ctrl-C and SIGTERM end a command within seconds, even inside a long C call."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest
from click.testing import CliRunner

from btel.cli import main
from btel.cli._signals import GRACE_SECONDS

#: A command added to btel's group for the test: ``slow --c`` spends a minute or more in one LAPACK call
#: (a 4000 × 4000 SVD on one thread), during which Python runs no signal handler; ``slow`` sleeps in Python.
SCRIPT = textwrap.dedent('''
    import sys, time
    import click
    import numpy as np
    from btel.cli import main

    @click.command("slow")
    @click.option("--c", is_flag=True)
    def slow(c):
        a = np.random.default_rng(0).standard_normal((4000, 4000)) if c else None
        click.echo("started", err=True)
        if c:
            np.linalg.svd(a)
        else:
            try:
                time.sleep(120)
            finally:
                click.echo("clean-up ran", err=True)

    main.add_command(slow)
    main(sys.argv[1:])
''')


def _signalled(tmp_path: Path, sig: int, *args: str) -> tuple[int, str, float]:
    """Exit status, stderr and seconds from the signal to the end of ``slow ARGS`` signalled once started."""
    script = tmp_path / "slow.py"
    script.write_text(SCRIPT)
    env = {**os.environ, "OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
    proc = subprocess.Popen([sys.executable, str(script), "slow", *args], stderr=subprocess.PIPE, env=env,
                            text=True)
    assert proc.stderr is not None
    assert proc.stderr.readline().strip() == "started"
    time.sleep(1.0)  # inside the SVD (or the sleep) by now
    sent = time.monotonic()
    proc.send_signal(sig)
    try:
        rest = proc.stderr.read()
        status = proc.wait(timeout=60)
    finally:
        proc.kill()
    return status, rest, time.monotonic() - sent


@pytest.mark.slow
@pytest.mark.parametrize(("sig", "status", "said"), [(signal.SIGTERM, 143, "Terminated (SIGTERM)"),
                                                    (signal.SIGINT, 130, "Interrupted")])
def test_a_signal_ends_a_command_held_in_a_long_c_call(tmp_path: Path, sig: int, status: int, said: str) -> None:
    got, stderr, seconds = _signalled(tmp_path, sig, "--c")
    assert got == status, stderr
    assert f"{said} in the middle of a computation that cannot stop itself" in stderr
    # The SVD alone takes far longer (tens of seconds on one thread); the process ends after the grace period.
    assert seconds < GRACE_SECONDS + 15


@pytest.mark.slow
def test_a_signal_between_bytecodes_runs_the_clean_up_as_before(tmp_path: Path) -> None:
    got, stderr, _ = _signalled(tmp_path, signal.SIGTERM)
    assert got == 143
    assert "clean-up ran" in stderr and "Terminated (SIGTERM)." in stderr
    assert "cannot stop itself" not in stderr


def test_a_command_run_in_process_gives_back_the_handlers_and_the_wakeup_file() -> None:
    def mine(signum: int, frame: object) -> None:  # a caller's own handler
        pass

    before_term = signal.signal(signal.SIGTERM, mine)
    try:
        result = CliRunner().invoke(main, ["methods"])
        assert result.exit_code == 0
        assert signal.getsignal(signal.SIGTERM) is mine
        assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
        assert signal.set_wakeup_fd(-1) == -1  # nothing left behind to write signals to
    finally:
        signal.signal(signal.SIGTERM, before_term)
