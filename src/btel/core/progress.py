"""Progress on stderr: a bar on a terminal, a line now and then in a log, the time elapsed for a step
that shows no progress of its own."""

from __future__ import annotations

import contextlib
import sys
import threading
import time
from collections.abc import Iterator
from typing import Any

__all__ = ["elapsed_ticker", "progress_bar", "LineProgress"]


@contextlib.contextmanager
def elapsed_ticker(desc: str, enabled: bool, file: Any = None) -> Iterator[None]:
    """A line on stderr with the time elapsed, refreshed twice a second, while a step that shows no
    progress of its own runs (a fit of a large map can take minutes); removed when the step ends.
    Where stderr is no terminal (a log), a line every :data:`LINE_EVERY_SECONDS` instead.

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
    stream = file or sys.stderr
    if not getattr(stream, "isatty", lambda: False)():  # a log: a line every LINE_EVERY_SECONDS, no bar
        bar, period = _ElapsedLines(desc, stream), LINE_EVERY_SECONDS
    else:
        from tqdm import tqdm

        bar, period = tqdm(total=None, desc=desc, bar_format="{desc} … {elapsed}", file=stream, leave=False), 0.5
    stop = threading.Event()

    def tick() -> None:
        while not stop.wait(period):
            bar.refresh()

    ticker = threading.Thread(target=tick, daemon=True)
    ticker.start()
    try:
        yield
    finally:
        stop.set()
        ticker.join()
        bar.close()


#: Seconds between two progress lines in a log (:class:`LineProgress`).
LINE_EVERY_SECONDS = 10.0


def _clock(seconds: float) -> str:
    """``m:ss`` of whole seconds, as the log lines show time elapsed."""
    whole = int(seconds)
    return f"{whole // 60}:{whole % 60:02d}"


class _ElapsedLines:
    """:func:`elapsed_ticker` in a log: ``desc: 0:20 elapsed`` on each refresh, nothing on close."""

    def __init__(self, desc: str, file: Any) -> None:
        self.desc, self.file, self.start = desc, file, time.monotonic()

    def refresh(self) -> None:
        print(f"{self.desc}: {_clock(time.monotonic() - self.start)} elapsed", file=self.file, flush=True)

    def close(self) -> None:
        pass


class LineProgress:
    """Where stderr is no terminal (a log file, a pipe, a batch job): a line ``desc: done/total units (postfix),
    elapsed`` at most every ``every`` seconds and one at the end, with tqdm's ``update``, ``set_postfix_str``
    and ``close`` — a long step in a log is not silent for minutes, nor one line per step."""

    def __init__(self, total: int, desc: str, unit: str, every: float | None = None, file: Any = None) -> None:
        self.total, self.desc, self.unit = total, desc, unit
        self.every = LINE_EVERY_SECONDS if every is None else every
        self.file = file or sys.stderr
        self.done, self.postfix, self.shown = 0, "", 0
        self.start = self.last = time.monotonic()

    def update(self, n: int = 1) -> None:
        self.done += n
        if n and time.monotonic() - self.last >= self.every:
            self._line()

    def set_postfix_str(self, text: str) -> None:
        self.postfix = text

    def close(self) -> None:
        if self.shown and self.shown != self.done:  # the last state, once anything was said
            self._line()

    def _line(self) -> None:
        self.last, self.shown = time.monotonic(), self.done
        units = self.unit[:-1] + "ies" if self.unit.endswith("y") else self.unit + "s"
        print(f"{self.desc}: {self.done}/{self.total} {units} done"
              + (f" (now {self.postfix})" if self.postfix and self.done < self.total else "")
              + f", {_clock(self.last - self.start)} elapsed", file=self.file, flush=True)


def progress_bar(total: int, desc: str, unit: str, enabled: bool) -> Any:
    """tqdm's bar on a terminal (or a notebook); :class:`LineProgress` where stderr is none; nothing when not
    ``enabled``. Either takes ``update``, ``set_postfix_str`` and ``close``."""
    from tqdm.auto import tqdm

    bar = tqdm(total=total, desc=desc, unit=unit, disable=None if enabled else True, leave=False)
    return LineProgress(total, desc, unit) if enabled and bar.disable else bar
