"""A line on stderr with the elapsed time while a step that shows no progress of its own runs."""

from __future__ import annotations

import contextlib
import sys
import threading
from collections.abc import Iterator
from typing import Any

__all__ = ["elapsed_ticker"]


@contextlib.contextmanager
def elapsed_ticker(desc: str, enabled: bool, file: Any = None) -> Iterator[None]:
    """A line on stderr with the time elapsed, refreshed twice a second, while a step that shows no
    progress of its own runs (a fit of a large map can take minutes); removed when the step ends.

    Parameters
    ----------
    desc : str
        What is running, e.g. ``"fitting auto on 10000 × 16384"``.
    enabled : bool
        False: nothing is shown (not a terminal, ``--no-progress``, or the step has its own bar).
    file : text stream, optional
        Where the line goes (default ``sys.stderr``).
    """
    if not enabled:
        yield
        return
    from tqdm import tqdm

    bar = tqdm(total=None, desc=desc, bar_format="{desc} … {elapsed}", file=file or sys.stderr, leave=False)
    stop = threading.Event()

    def tick() -> None:
        while not stop.wait(0.5):
            bar.refresh()

    ticker = threading.Thread(target=tick, daemon=True)
    ticker.start()
    try:
        yield
    finally:
        stop.set()
        ticker.join()
        bar.close()
