"""Writers that cannot collide: an atomic claim on a folder, atomic output files, and the removal of
dead writers' leftovers.

A claim is a lock file created with ``O_CREAT | O_EXCL`` (atomic on POSIX and Windows local file
systems) holding the writer's process id. An output file is written through a uniquely named
temporary beside it (:func:`atomic_output`) and published in one step: renamed over the target
when replacing is asked for, else hard-linked to it, which fails when the target exists — so of
two writers that both found the name free exactly one publishes, and the other gets
:class:`~btel.exceptions.OutputExistsError` with nothing replaced. A failed write (a full disk, a
file size limit, Ctrl-C) removes its temporary; every output gets the mode a plain ``open`` gives
(``0666`` less the umask). A claim or temporary whose process is no longer alive is stale: it is
removed, so a SIGKILLed run or save does not block or litter the folder forever. Process ids are
local: folders shared between machines over a network file system are not protected against each
other.
"""

from __future__ import annotations

import contextlib
import errno
import os
import re
import secrets
from collections.abc import Iterator
from pathlib import Path
from typing import IO, Any

__all__ = ["pid_alive", "claim", "release", "temp_prefix", "remove_stale_temporaries", "atomic_output",
           "publish", "fsync_folder", "write_error"]


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
    OutputExistsError
        Another live process holds the claim (its process id is named); a ``FileExistsError``.
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
            from ..exceptions import OutputExistsError

            raise OutputExistsError(
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


def fsync_folder(folder: Path) -> None:
    """Flush a folder's entries to disk where the system allows it (POSIX); best effort."""
    try:
        fd = os.open(folder, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


#: errno values of a file system that has no hard links: publishing falls back to an exclusive create.
_NO_LINKS = {errno.EPERM, errno.EXDEV, errno.EMLINK, errno.ENOSYS, errno.EOPNOTSUPP,
             getattr(errno, "ENOTSUP", errno.EOPNOTSUPP)}


def _taken(path: Path) -> Exception:
    from ..exceptions import OutputExistsError

    return OutputExistsError(
        f"{str(path)!r} already exists (another process wrote it while this one was writing); it was kept "
        "and nothing was written. Pass overwrite=True (CLI: --overwrite) to replace it, or choose another "
        "name.")


def publish(tmp: Path, path: Path, *, overwrite: bool) -> None:
    """Give the complete temporary ``tmp`` the name ``path`` in one step.

    With ``overwrite`` a rename over whatever is there; without, a hard link that fails when ``path``
    exists (on a file system without hard links: an exclusive create of ``path``, then the rename).

    Raises
    ------
    OutputExistsError
        ``path`` exists and ``overwrite`` is False (``tmp`` is left for the caller to remove).
    """
    if overwrite:
        os.replace(tmp, path)
        return
    try:
        os.link(tmp, path)
    except FileExistsError:
        raise _taken(path) from None
    except OSError as exc:
        if exc.errno not in _NO_LINKS:
            raise
        try:
            os.close(os.open(path, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o666))
        except FileExistsError:
            raise _taken(path) from None
        try:
            os.replace(tmp, path)
        except BaseException:
            with contextlib.suppress(OSError):
                os.unlink(path)  # the empty placeholder this call created
            raise
        return
    with contextlib.suppress(OSError):
        tmp.unlink()


def _create_temporary(folder: Path, prefix: str, suffix: str) -> tuple[int, Path]:
    """A new file ``PREFIX<random>SUFFIX`` in ``folder``, created exclusively with mode 0666: the system
    applies the umask in force now, as ``open`` does (``mkstemp`` would give 0600)."""
    flags = os.O_CREAT | os.O_EXCL | os.O_WRONLY | getattr(os, "O_BINARY", 0)
    for _ in range(100):
        tmp = folder / f"{prefix}{secrets.token_hex(4)}{suffix}"
        try:
            return os.open(tmp, flags, 0o666), tmp
        except FileExistsError:
            continue
    raise FileExistsError(errno.EEXIST, f"no free temporary name for {prefix!r} in {str(folder)!r}")


def refuse_special_target(path: Path) -> None:
    """Refuse to publish over a device, FIFO or socket (or a link to one): the rename would replace
    ``/dev/null`` or a named pipe with a regular file, whatever ``overwrite`` says.

    Raises
    ------
    OutputExistsError
        ``path`` exists and is neither a regular file nor a link to one.
    """
    import stat

    from ..exceptions import OutputExistsError

    try:
        mode = os.stat(path).st_mode
    except OSError:  # nothing there (or a broken link, replaced as a file would be)
        return
    if not stat.S_ISREG(mode) and not stat.S_ISDIR(mode):
        kind = ("a FIFO (named pipe)" if stat.S_ISFIFO(mode) else "a socket" if stat.S_ISSOCK(mode)
                else "a device")
        raise OutputExistsError(f"{str(path)!r} is {kind}, not a file; btel writes its outputs as regular "
                                "files and never replaces anything else (--overwrite included): give a file name.")


@contextlib.contextmanager
def atomic_output(path: str | os.PathLike, *, overwrite: bool = True, text: bool = False,
                  suffix: str = ".part") -> Iterator[IO[Any]]:
    """A file object whose contents appear at ``path`` only once they are complete (module docstring).

    Yields a handle on ``.NAME.PID.XXXX<suffix>`` beside ``path`` (text: UTF-8, no newline
    translation); on leaving the block the data are flushed to disk and published
    (:func:`publish`). Any failure removes the temporary; an ``OSError`` of the write is raised
    again as one naming ``path`` and saying nothing was left behind.

    Raises
    ------
    OutputExistsError
        ``overwrite`` is False and ``path`` exists when the file is published.
    OSError
        The file could not be written (disk full, file size limit, no permission…).
    """
    from ..exceptions import OutputExistsError

    path = Path(path)
    folder = path.parent
    refuse_special_target(path)
    remove_stale_temporaries(folder, path.name, suffix)  # killed writers' leftovers
    fd, tmp = _create_temporary(folder, temp_prefix(path.name), suffix)
    try:
        options = {"encoding": "utf-8", "newline": ""} if text else {}
        with os.fdopen(fd, "w" if text else "wb", **options) as fh:
            yield fh
            fh.flush()
            os.fsync(fh.fileno())
        publish(tmp, path, overwrite=overwrite)
        fsync_folder(folder)  # the new name survives a power cut
    except BaseException as exc:  # KeyboardInterrupt included: never leave the temporary behind
        with contextlib.suppress(OSError):
            tmp.unlink()
        if isinstance(exc, OSError) and not isinstance(exc, OutputExistsError):
            reason = exc.strerror or str(exc)
            if exc.errno is None:  # numpy's short write: "N requested and M written"
                reason += " (the disk is full or a file size limit was reached)"
            message = f"could not write {str(path)!r} ({reason}); nothing was left behind"
            raise write_error(exc.errno, message) from exc
        raise


def write_error(code: int | None, message: str) -> OSError:
    """An ``OSError`` whose text is ``message`` alone (no ``[Errno N]`` prefix), its errno ``code``."""
    error = OSError(message)
    error.errno = code
    return error
