"""Ctrl-C and SIGTERM end a command promptly, even in the middle of a long computation.

Python runs a signal handler only between bytecodes. While faiss trains or BLAS factorises — minutes
on a large map — the handler waits, so ``timeout 60 btel train …`` would run on past its limit and
Ctrl-C would seem ignored. Here each handler first notes that the main thread took the signal; then the
clean-up written for Ctrl-C runs (a run's finished rows written, its folder released). A watch thread
is woken by the signal itself: CPython's C-level handler writes the signal number to the file given to
:func:`signal.set_wakeup_fd`, whatever the main thread is doing. If the main thread has not taken the
signal within :data:`GRACE_SECONDS`, the watch thread ends the process with the signal's exit status.
The work in progress is then lost. What was already written stays: outputs are published atomically,
and a dead process's claims and temporaries are removed by the next run (:mod:`btel.core.claims`).
"""

from __future__ import annotations

import contextlib
import os
import signal
import threading
import time
from collections.abc import Iterator

from ._errors import EXIT_INTERRUPTED, EXIT_TERMINATED, Terminated

__all__ = ["GRACE_SECONDS", "ending_on_signals"]

#: Seconds the main thread has to take Ctrl-C or SIGTERM before the process ends without it.
GRACE_SECONDS = 3.0
_STATUS = {signal.SIGINT: EXIT_INTERRUPTED, signal.SIGTERM: EXIT_TERMINATED}
_SAID = {signal.SIGINT: "Interrupted", signal.SIGTERM: "Terminated (SIGTERM)"}
_STOP = b"\0"  # no signal has number 0: the command is over, the watch thread returns


class _Taken:
    """How many signals the main thread's handlers took (a counter: a second signal waits for its own turn)."""

    def __init__(self) -> None:
        self.count = 0


@contextlib.contextmanager
def ending_on_signals() -> Iterator[None]:
    """For the duration of a command in the main thread: SIGTERM raises :class:`Terminated` (as Ctrl-C raises
    KeyboardInterrupt), and either signal ends the process within :data:`GRACE_SECONDS` if the main thread is
    held in a C call. Elsewhere (another thread, a caller with its own wakeup file) only the handler is set."""
    taken = _Taken()

    def on_term(signum: int, frame: object) -> None:
        taken.count += 1
        raise Terminated()

    def on_int(signum: int, frame: object) -> None:
        taken.count += 1
        raise KeyboardInterrupt

    try:
        previous_term = signal.signal(signal.SIGTERM, on_term)
    except ValueError:  # not the main thread: no handler can be set, Python's defaults stay
        yield
        return
    previous_int = signal.getsignal(signal.SIGINT)
    own_int = previous_int is signal.default_int_handler  # a caller's own Ctrl-C handler is left alone
    if own_int:
        signal.signal(signal.SIGINT, on_int)
    read_fd, write_fd = os.pipe()
    os.set_blocking(write_fd, False)
    previous_fd = signal.set_wakeup_fd(write_fd, warn_on_full_buffer=False)
    watcher = None
    if previous_fd == -1:
        watcher = threading.Thread(target=_watch, args=(read_fd, taken, own_int), name="btel-signals", daemon=True)
        watcher.start()
    else:  # someone else reads signals this way (an event loop): give its file back, watch nothing
        signal.set_wakeup_fd(previous_fd)
    try:
        yield
    finally:
        if watcher is not None:
            signal.set_wakeup_fd(-1)
            with contextlib.suppress(OSError):
                os.write(write_fd, _STOP)
            watcher.join(timeout=1.0)
        signal.signal(signal.SIGTERM, previous_term)
        if own_int:
            signal.signal(signal.SIGINT, previous_int)
        os.close(write_fd)
        if watcher is None or not watcher.is_alive():
            os.close(read_fd)


def _watch(read_fd: int, taken: _Taken, watch_int: bool) -> None:
    """Wait for signal numbers on ``read_fd``; end the process when the main thread does not take one in time."""
    arrived = 0
    watched = {signal.SIGTERM, *((signal.SIGINT,) if watch_int else ())}
    while True:
        try:
            data = os.read(read_fd, 64)
        except OSError:
            return
        if not data or _STOP in data:
            return
        for number in data:
            if number not in watched:
                continue
            arrived += 1
            deadline = time.monotonic() + GRACE_SECONDS
            while taken.count < arrived and time.monotonic() < deadline:
                time.sleep(0.05)
            if taken.count < arrived:
                os.write(2, f"{_SAID[number]} in the middle of a computation that cannot stop itself: the work in "
                            "progress is lost; what was already written is kept.\n".encode())
                os._exit(_STATUS[number])
