"""One resource budget for what an input file may make btel allocate or compute.

Every reader of untrusted input (ground truth, descriptor files, HDF5, saved descriptor
parameters, model files) checks the memory a file *declares* it needs against one limit **before**
allocating it, so a tiny hostile file cannot ask for gigabytes or hours.

The limit is :data:`DEFAULT_MEMORY_LIMIT` (256 MiB) unless the environment variable
``BTEL_MEMORY_LIMIT`` sets another: a number of bytes, optionally with a unit ``K``, ``M``, ``G``
or ``T`` (binary: ``BTEL_MEMORY_LIMIT=4G`` is 4 GiB). Raise it for legitimately large inputs.
"""

from __future__ import annotations

import math
import os
import re
from typing import Any

from ..exceptions import ResourceLimitError

__all__ = ["DEFAULT_MEMORY_LIMIT", "ENV_MEMORY_LIMIT", "memory_limit", "check_bytes", "check_count",
           "check_fits_machine", "physical_memory",
           "format_size", "check_numpy_file", "open_regular",
           "BYTES_PER_PLACE", "check_places"]

#: Bytes one input may make btel allocate when ``BTEL_MEMORY_LIMIT`` is not set.
DEFAULT_MEMORY_LIMIT = 256 * 2**20
#: Environment variable that raises (or lowers) the limit.
ENV_MEMORY_LIMIT = "BTEL_MEMORY_LIMIT"

#: Bytes per map place that answering one query may need: an HMM step holds five float64 vectors over
#: the places (the query's scores, the belief, the emission, the moved belief, one workspace; 305 MiB
#: at N = 8·10⁶ under tracemalloc). A model's N may be at most ``memory_limit() // BYTES_PER_PLACE``
#: (6,710,886 places under the 256 MiB default).
BYTES_PER_PLACE = 40

_UNITS = {"": 1, "B": 1, "K": 2**10, "M": 2**20, "G": 2**30, "T": 2**40}


def memory_limit() -> int:
    """The memory limit in bytes (``BTEL_MEMORY_LIMIT`` or the 256 MiB default).

    Raises
    ------
    InvalidParameterError
        ``BTEL_MEMORY_LIMIT`` is not a positive size such as ``1073741824``, ``512M`` or ``4G``.
    """
    from ..exceptions import InvalidParameterError

    text = os.environ.get(ENV_MEMORY_LIMIT, "").strip()
    if not text:
        return DEFAULT_MEMORY_LIMIT
    match = re.fullmatch(r"([0-9]{1,15})\s*([KMGT]?)(?:i?B)?", text, flags=re.IGNORECASE)
    if match is None or int(match.group(1)) <= 0:
        raise InvalidParameterError(
            f"{ENV_MEMORY_LIMIT}={text!r} is not a size; give bytes or a number with K, M, G or T (e.g. 4G).")
    return int(match.group(1)) * _UNITS[match.group(2).upper()]


def format_size(n_bytes: float) -> str:
    """``1536`` → ``"1.5 KiB"`` (for messages)."""
    if not math.isfinite(n_bytes):
        return "an unbounded amount"
    value = float(n_bytes)
    for unit in ("B", "KiB", "MiB", "GiB", "TiB", "PiB"):
        if value < 1024 or unit == "PiB":
            return f"{value:.0f} {unit}" if unit == "B" else f"{value:.1f} {unit}"
        value /= 1024
    return f"{value:.1f} PiB"  # pragma: no cover


def check_bytes(n_bytes: float, what: str) -> None:
    """Raise :class:`ResourceLimitError` when ``n_bytes`` (declared by an input) exceeds the limit.

    Parameters
    ----------
    n_bytes : int or float
        Bytes the work would allocate (may be astronomically large; never allocated here).
    what : str
        What needs them, for the message (e.g. ``"ground truth 'gt.npy' (3 × 10⁹ positives)"``).
    """
    limit = memory_limit()
    if not n_bytes <= limit:  # also catches NaN
        raise ResourceLimitError(
            f"{what} would need {format_size(n_bytes)}, over btel's memory limit of {format_size(limit)}; "
            f"if the input is genuine, raise the limit with {ENV_MEMORY_LIMIT} (e.g. {ENV_MEMORY_LIMIT}=4G).")


def physical_memory() -> int | None:
    """Bytes of memory this machine has (None where the system does not say)."""
    try:
        return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (AttributeError, ValueError, OSError):
        return None


def check_fits_machine(n_bytes: float, what: str, fix: str) -> None:
    """Raise :class:`ResourceLimitError` when work the user asked for (not a file's claim: that is
    :func:`check_bytes`) would need more bytes than the machine has; ``fix`` says what to ask instead."""
    memory = physical_memory()
    if memory is not None and not n_bytes <= memory:
        raise ResourceLimitError(f"{what} would need {format_size(n_bytes)} and this machine has "
                                 f"{format_size(memory)}; {fix}")


def check_count(count: float, itemsize: int, what: str) -> None:
    """:func:`check_bytes` for ``count`` items of ``itemsize`` bytes each."""
    check_bytes(float(count) * itemsize, what)


def check_places(n_places: int, what: str) -> None:
    """Refuse a model whose N would make one query's inference exceed the limit (see
    :data:`BYTES_PER_PLACE`), before any query runs: a tiny file may claim N = 2³²."""
    check_bytes(float(n_places) * BYTES_PER_PLACE, f"{what} with N = {n_places} places (per query)")


#: Most members an .npz may list (a model, descriptor or ground-truth archive holds a few arrays): the zip
#: directory is parsed whole, some 1 KB of memory per entry, before any member can be checked.
MAX_ZIP_MEMBERS = 1024


def check_zip_members(fh: Any, what: str, most: int = MAX_ZIP_MEMBERS) -> None:
    """Refuse a zip archive whose end record lists more than ``most`` entries, before its directory is parsed.

    ``fh`` is a binary file positioned anywhere (it is left at 0). An archive without a readable end
    record is left for the zip reader to report.

    Raises
    ------
    ResourceLimitError
        Too many entries listed.
    """
    import zipfile

    try:  # the end record alone (22 bytes, or its zip64 form): zipfile's own reader of it
        end = zipfile._EndRecData(fh)  # type: ignore[attr-defined]
        listed = None if end is None else int(end[zipfile._ECD_ENTRIES_TOTAL])  # type: ignore[attr-defined]
    except Exception:  # a private helper of zipfile: should it change, ZipFile's own parse is still bounded
        listed = None
    finally:
        fh.seek(0)
    refuse_zip_members(listed or 0, what, most)


def refuse_zip_members(listed: int, what: str, most: int = MAX_ZIP_MEMBERS) -> None:
    """:class:`ResourceLimitError` for an archive of more than ``most`` members (:func:`check_zip_members`)."""
    from ..exceptions import ResourceLimitError

    if listed > most:
        raise ResourceLimitError(f"{what} lists {listed:,} archive members; btel reads .npz archives of at most "
                                 f"{most} arrays (a model, descriptor or ground-truth file holds a few).")


def check_numpy_file(path: "os.PathLike[str] | str", what: str) -> None:
    """Check what an ``.npy`` or ``.npz`` file declares against the limit before numpy reads it.

    numpy allocates ``prod(shape) × itemsize`` bytes from an array's header before reading its
    data, and an ``.npz`` member may decompress to far more than its compressed size (a zip bomb).
    This reads only the headers: an ``.npy``'s own, and for an ``.npz`` each member's zip entry
    (declared uncompressed size) and ``.npy`` header. Damaged files are left for numpy to report.

    Raises
    ------
    ResourceLimitError
        The arrays together declare more bytes than :func:`memory_limit`.
    """
    import zipfile

    import numpy as np

    def declared(fh: Any) -> float:
        try:
            version = np.lib.format.read_magic(fh)
            reader = (np.lib.format.read_array_header_1_0 if version == (1, 0)
                      else np.lib.format.read_array_header_2_0)
            shape, _, dtype = reader(fh)
        except Exception:  # not an .npy header: numpy's own reader names the problem
            return 0.0
        return float(math.prod(shape)) * max(dtype.itemsize, 1)

    total = 0.0
    with open(path, "rb") as fh:
        magic = fh.read(4)
        fh.seek(0)
        if magic.startswith(b"PK"):
            check_zip_members(fh, what)
            try:
                archive = zipfile.ZipFile(fh)
            except Exception:  # BadZipFile, NotImplementedError (odd versions)…: numpy's reader names it
                return
            with archive:
                infos = archive.infolist()  # read by ZipFile() already: no further parsing here
                refuse_zip_members(len(infos), what)  # a directory longer than its end record said
                total = float(sum(info.file_size for info in infos))
                check_bytes(total, f"{what} (decompressed)")
                total = 0.0
                for info in infos:
                    try:
                        with archive.open(info) as member:
                            total += declared(member)
                    except Exception:  # damaged member: numpy reports it when reading
                        continue
        else:
            total = declared(fh)
    check_bytes(total, what)


def open_regular(path: "os.PathLike[str] | str") -> Any:
    """Open a regular file for reading; a FIFO, device or socket is refused without blocking."""
    import stat

    from ..exceptions import DataNotFoundError

    try:
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0))
    except OSError as exc:
        raise DataNotFoundError(f"{str(path)!r} could not be opened: {exc.strerror}.") from exc
    if not stat.S_ISREG(os.fstat(fd).st_mode):
        os.close(fd)
        raise DataNotFoundError(f"{str(path)!r} is not a regular file (a FIFO, device or socket); give a file.")
    if hasattr(os, "set_blocking"):
        os.set_blocking(fd, True)
    return os.fdopen(fd, "rb")


def read_regular(path: "os.PathLike[str] | str", what: str, *, expansion: float = 1.0) -> bytes:
    """The bytes of a regular file, at most the memory limit (divided by ``expansion``, what parsing them
    costs per byte) of them, however large the file says it is: a /proc file says 0 bytes and never ends.

    Raises
    ------
    DataNotFoundError
        Not a regular file, or it cannot be opened or read (the message names ``what`` and the reason).
    ResourceLimitError
        The file holds more than that.
    """
    from ..exceptions import DataNotFoundError

    room = int(memory_limit() / expansion)
    from ..exceptions import ResourceLimitError

    with open_regular(path) as fh:
        size = os.fstat(fh.fileno()).st_size
        check_bytes(size * expansion, what)
        try:
            data = fh.read(room + 1)
        except OSError as exc:  # an I/O error, or a kernel file that cannot be read as a stream
            raise DataNotFoundError(f"{what} could not be read: {exc.strerror or exc}.") from None
    if len(data) > room:
        raise ResourceLimitError(
            f"{what} holds more than its size says ({size} B): over {format_size(room)} were read, btel's memory "
            f"limit for it. A file that grows while read, or a kernel file (/proc, /sys), is not an input; if the "
            f"file is genuine, raise the limit with {ENV_MEMORY_LIMIT} (e.g. {ENV_MEMORY_LIMIT}=4G).")
    return data

