"""Writers that cannot collide: an atomic claim on a folder and the removal of dead writers' leftovers.

A claim is a lock file created with ``O_CREAT | O_EXCL`` (atomic on POSIX and Windows local file
systems) holding the writer's process id. A claim or temporary file whose process is no longer
alive is stale: it is removed, so a SIGKILLed run or save does not block or litter the folder
forever. Process ids are local: folders shared between machines over a network file system are
not protected against each other.
"""

from __future__ import annotations

import contextlib
import os
import re
from pathlib import Path

__all__ = ["pid_alive", "claim", "release", "temp_prefix", "remove_stale_temporaries"]


def pid_alive(pid: int) -> bool:
    """Whether a process with this id exists on this machine (unknown ids count as alive)."""
    if pid <= 0:
        return False
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except (PermissionError, OSError, OverflowError):
        return True  # exists but belongs to someone else, or cannot tell: keep it
    return True


def _owner(lock: Path) -> int | None:
    try:
        text = lock.read_text(encoding="ascii", errors="replace")[:64]
    except OSError:
        return None
    match = re.match(r"\s*(\d{1,10})\b", text)
    return int(match.group(1)) if match else None


def claim(folder: Path, name: str = ".btel-run.lock") -> Path:
    """Atomically claim ``folder`` for this process; return the lock file.

    Raises
    ------
    FileExistsError
        Another live process holds the claim (its process id is named).
    """
    lock = folder / name
    for _ in range(3):
        try:
            fd = os.open(lock, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
        except FileExistsError:
            owner = _owner(lock)
            # A dead writer's claim, or one this process left behind (a run that raised).
            if owner is not None and (owner == os.getpid() or not pid_alive(owner)):
                with contextlib.suppress(FileNotFoundError):
                    lock.unlink()
                continue
            raise FileExistsError(
                f"another btel run (process {owner if owner is not None else 'unknown'}) is writing to "
                f"{str(folder)!r}; wait for it to finish or choose another --out folder"
                + ("" if owner is not None else f" (remove {str(lock)!r} if no run is active)") + ".") from None
        with os.fdopen(fd, "w", encoding="ascii") as fh:
            fh.write(f"{os.getpid()}\n")
        return lock
    raise FileExistsError(f"could not claim {str(folder)!r}: its lock file keeps reappearing.")


def release(lock: Path | None) -> None:
    """Remove a claim made by this process (no error when it is already gone)."""
    if lock is not None and _owner(lock) == os.getpid():
        with contextlib.suppress(OSError):
            lock.unlink()


def temp_prefix(name: str) -> str:
    """Prefix of a temporary for ``name`` that records this process: ``.NAME.PID.``"""
    return f".{name}.{os.getpid()}."


def remove_stale_temporaries(folder: Path, name: str, suffix: str) -> int:
    """Remove ``.NAME.PID.*SUFFIX`` temporaries whose process is dead; return how many."""
    removed = 0
    pattern = re.compile(re.escape(f".{name}.") + r"(\d{1,10})\..*" + re.escape(suffix) + r"$")
    try:
        entries = list(os.scandir(folder))
    except OSError:
        return 0
    for entry in entries:
        match = pattern.match(entry.name)
        if match and not pid_alive(int(match.group(1))):
            with contextlib.suppress(OSError):
                os.unlink(entry.path)
                removed += 1
    return removed
