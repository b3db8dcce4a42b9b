"""Descriptor matrices computed by other tools (NetVLAD, DenseVLAD in MATLAB, hloc, ...).

Row i is the global descriptor of image (place) i. Formats:

- ``.npy`` / ``.npz``, read with ``allow_pickle=False``: nothing in a descriptor file can run code;
- ``.h5`` / ``.hdf5`` as written by hloc's ``extract_features`` for global descriptors (NetVLAD,
  OpenIBL, EigenPlaces, ...): one HDF5 group per image name holding a ``global_descriptor``
  dataset. Image names may contain ``/`` (hloc then nests groups: ``db/0001.jpg``). Rows are the
  images in **natural name order** (``img2`` before ``img10``), which is the route order when the
  file names are frame numbers; ``PATH.h5:PREFIX`` keeps only the names starting with ``PREFIX``
  (hloc often keeps map and query images in one file, e.g. ``feats.h5:db/`` and ``feats.h5:query/``).
  HDF5 holds plain arrays only; h5py reads no pickles. External storage, virtual datasets, links
  and non-numeric dtypes are refused (see :mod:`btel.descriptors.hdf5`).

A memory-mapped ``.npy`` (``mmap_mode="r"``) stays a view of the file only when it is C-ordered
float32. Any other layout or dtype is converted from the file in row blocks (never through a whole
copy of the source) when the float32 result fits :func:`btel.core.limits.memory_limit`, and refused
otherwise with the one-line command that rewrites the file as C-ordered float32
(:func:`to_float32_npy`, which converts in blocks too).
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from ..core.validation import check_descriptors
from ..exceptions import DataNotFoundError, InvalidDescriptorsError, InvalidParameterError, ResourceLimitError
from ..core.limits import ENV_MEMORY_LIMIT, check_numpy_file, format_size, memory_limit, open_regular
from ..core.modelfile import HEADER_KEY
from .hdf5 import load_hloc_global
from .npy_header import check_npy_header, refuse_text_matrix

__all__ = ["load_descriptor_matrix", "load_hloc_global", "to_float32_npy", "HDF5_SUFFIXES"]

HDF5_SUFFIXES = (".h5", ".hdf5")
#: Values converted per block when a memory-mapped matrix is rewritten as float32.
_BLOCK_VALUES = 1 << 21


def _row_blocks(mapped: np.memmap) -> Iterator[tuple[int, np.ndarray]]:
    """(first row, rows) of the memory-mapped 2-D ``mapped``, read from its file in blocks of about
    :data:`_BLOCK_VALUES` values with plain reads: no page of the mapping is touched, so neither
    the mapping nor a whole copy of it grows the process's memory. Fortran-ordered files are read
    one column run per block and column."""
    n, d = mapped.shape
    dtype, offset = mapped.dtype, int(mapped.offset)
    fortran = bool(mapped.flags.f_contiguous and not mapped.flags.c_contiguous)
    rows = max(1, _BLOCK_VALUES // max(d, 1))
    with open(mapped.filename, "rb") as fh:
        for start in range(0, n, rows):
            stop = min(n, start + rows)
            if not fortran:
                fh.seek(offset + start * d * dtype.itemsize)
                block = np.fromfile(fh, dtype=dtype, count=(stop - start) * d).reshape(stop - start, d)
            else:
                block = np.empty((stop - start, d), dtype=dtype)
                for j in range(d):
                    fh.seek(offset + (j * n + start) * dtype.itemsize)
                    block[:, j] = np.fromfile(fh, dtype=dtype, count=stop - start)
            yield start, block


def _mapped_as_float32(mapped: np.memmap, path: Path) -> np.ndarray:
    """``mapped`` (a 2-D numeric ``.npy`` mapping that is not C-ordered float32) as float32 in
    memory, converted block by block, or :class:`ResourceLimitError` naming the rewrite."""
    n, d = mapped.shape
    layout = "Fortran-ordered " if mapped.flags.f_contiguous and not mapped.flags.c_contiguous else ""
    target = path.with_name(path.stem + ".float32.npy")
    limit = memory_limit()
    if 4.0 * n * d > limit:
        rewrite = f"to_float32_npy({str(path)!r}, {str(target)!r})"
        raise ResourceLimitError(
            f"memory-mapping {str(path)!r} (a {layout}{mapped.dtype} matrix of {n} × {d}) would copy it "
            f"whole as C-ordered float32, {format_size(4.0 * n * d)}, over btel's memory limit of "
            f"{format_size(limit)}. Rewrite it once as C-ordered float32, which btel maps without a copy: "
            f"python -c \"from btel.descriptors.npy import to_float32_npy; {rewrite}\" (or raise "
            f"{ENV_MEMORY_LIMIT}).")
    out = np.empty((n, d), dtype=np.float32)
    wider = mapped.dtype.kind == "f" and mapped.dtype.itemsize > 4
    largest, kept = 0.0, not wider  # kept: some value is non-zero in float32
    for start, block in _row_blocks(mapped):
        converted = out[start:start + block.shape[0]]
        with np.errstate(over="ignore"):
            converted[...] = block
        if wider:
            over = np.isfinite(block) & ~np.isfinite(converted)
            if over.any():
                row, column = np.argwhere(over)[0]
                raise InvalidDescriptorsError(
                    f"{str(path)!r} holds {block[row, column]:g} at row {start + row}, column {column}, "
                    "beyond float32's range (±3.4e38); scale the descriptors.")
            kept = kept or bool(converted.any())
            largest = max(largest, float(np.abs(block).max(initial=0.0)))
    if not kept and largest > 0:  # every value underflowed: the matrix would be all zeros
        raise InvalidDescriptorsError(
            f"{str(path)!r} holds only values below float32's smallest number (largest |v| {largest:.3g}), "
            "which all become 0; scale the descriptors up.")
    return out


def to_float32_npy(source: str | os.PathLike, target: str | os.PathLike) -> Path:
    """Rewrite a 2-D numeric ``.npy`` as a C-ordered float32 ``.npy`` in blocks of rows.

    ``load_descriptor_matrix(target, mmap_mode="r")`` then maps the result without a copy.
    Memory stays a few MiB whatever the size of the matrix.

    Parameters
    ----------
    source : path
        A ``.npy`` holding a 2-D numeric matrix (any dtype and order numpy writes).
    target : path
        The file to write (replaced if it exists); must differ from ``source``.

    Returns
    -------
    Path
        ``target``.

    Raises
    ------
    InvalidDescriptorsError
        ``source`` is not a readable 2-D numeric ``.npy``.
    InvalidParameterError
        ``target`` is ``source``.
    """
    source, target = Path(source), Path(target)
    if target.resolve() == source.resolve():
        raise InvalidParameterError(
            f"to_float32_npy writes a new file; give a target other than {str(source)!r}.")
    mapped = _open_mapped(source, "r")
    if mapped.ndim != 2 or mapped.dtype.kind not in "biuf":
        raise InvalidDescriptorsError(f"{str(source)!r} holds a {mapped.dtype} array of shape "
                                      f"{mapped.shape}; descriptors are a 2-D numeric matrix.")
    with open(target, "wb") as fh:
        header = {"descr": "<f4", "fortran_order": False, "shape": mapped.shape}
        np.lib.format.write_array_header_1_0(fh, header)
        for _, block in _row_blocks(mapped):
            fh.write(block.astype("<f4").tobytes())
    return target


def split_prefix(path: str | os.PathLike) -> tuple[Path, str | None]:
    """``"feats.h5:db/"`` → (Path("feats.h5"), "db/"), ``"x.npz:hlrTrain"`` → (Path("x.npz"), "hlrTrain");
    a path that exists as given is kept whole."""
    text = os.fspath(path)
    if Path(text).exists() or ":" not in text:
        return Path(text), None
    head, _, prefix = text.rpartition(":")
    if Path(head).suffix.lower() in (*HDF5_SUFFIXES, ".npz"):
        return Path(head), prefix
    return Path(text), None


def load_descriptor_matrix(
    path: str | os.PathLike, *, mmap_mode: str | None = None, key: str | None = None
) -> np.ndarray:
    """Load and check an ``(n, d)`` descriptor matrix from a ``.npy`` (or ``.npz``) file.

    Parameters
    ----------
    path : str or path-like
        A ``.npy`` file, an ``.npz`` archive (then ``key`` names the array; it may be left
        out when the archive holds exactly one; ``PATH.npz:KEY`` names it too), or an hloc ``.h5`` file (``PATH.h5:PREFIX``
        selects the images whose name starts with PREFIX; see the module docstring).
    mmap_mode : {None, "r", "c"}
        ``"r"`` memory-maps a ``.npy`` read-only instead of reading it into memory, for maps
        larger than RAM; the result stays a view of the file when it is already float32 and
        C-ordered (otherwise it is converted in row blocks when the float32 copy fits the memory
        limit, else refused: see the module docstring). ``"c"`` is copy-on-write. Writable modes
        are refused: loading must never change the file. Not available for ``.npz``.
    key : str, optional
        Array name inside an ``.npz`` archive.

    Returns
    -------
    X : ndarray of shape (n, d), dtype float32
        Every value finite.

    Raises
    ------
    DataNotFoundError
        The file does not exist (or is a folder), or ``key`` is not in the archive.
    InvalidDescriptorsError
        Not a readable ``.npy``/``.npz``, pickled objects, not 2-D, not numeric, NaN/inf, empty.
    InvalidParameterError
        A writable or unknown ``mmap_mode``, or ``mmap_mode`` with an ``.npz``.
    ResourceLimitError
        The file declares more than :mod:`btel.core.limits` allows, or (memory-mapped) its float32
        copy would (the message gives the command that rewrites it).
    """
    path, prefix = split_prefix(path)
    if prefix is not None and path.suffix.lower() == ".npz":
        if key is not None and key != prefix:
            raise InvalidParameterError(f"{path}:{prefix} names array {prefix!r} but key={key!r}; give one.")
        key = prefix
    if path.suffix.lower() in HDF5_SUFFIXES:
        if key is not None:
            raise InvalidParameterError(f"key={key!r} only applies to .npz archives; write {path}:PREFIX instead.")
        return load_hloc_global(path, prefix)[0]
    if mmap_mode not in (None, "r", "c"):
        raise InvalidParameterError(
            f"mmap_mode must be None, 'r' or 'c'; got {mmap_mode!r} (writable maps could change the file)."
        )
    if not path.exists():
        if path.is_symlink():
            raise DataNotFoundError(f"descriptor file {str(path)!r} is a link that leads nowhere (a missing "
                                    "target, or a loop of links). Check the link.")
        raise DataNotFoundError(f"descriptor file {str(path)!r} does not exist. Check the path.")
    if path.is_dir():
        raise DataNotFoundError(f"{str(path)!r} is a folder; pass the .npy file inside it.")
    with open_regular(path):  # a FIFO, device or socket: named as such
        pass
    if path.suffix.lower() != ".npz":  # cut short, or a pickle inside: named before numpy maps or reads it
        check_npy_header(path, "descriptor file")
    if mmap_mode is None:
        check_numpy_file(path, f"descriptor file {str(path)!r}")
    loaded = _open_mapped(path, mmap_mode)
    if isinstance(loaded, np.lib.npyio.NpzFile):
        with loaded:
            if mmap_mode is not None:
                raise InvalidParameterError(f"{str(path)!r} is an .npz archive; memory-mapping needs a .npy file.")
            names = list(loaded.files)
            if HEADER_KEY in names:  # a saved model given where descriptors go (arguments swapped)
                raise InvalidDescriptorsError(
                    f"{str(path)!r} is a btel model file (written by `btel train` or model.save), not descriptors. "
                    "Give the descriptor matrix (.npy, .npz, hloc .h5) here; the model goes where a command "
                    f"takes MODEL: btel localize {path} QUERIES -o predictions.csv, or btel evaluate --model {path}.")
            if not names:
                raise InvalidDescriptorsError(f"{str(path)!r} is an .npz archive without arrays; save the "
                                              "descriptors with np.savez(path, X=X).")
            if key is None:
                if len(names) != 1:
                    raise InvalidParameterError(
                        f"{str(path)!r} holds {len(names)} arrays ({', '.join(names[:8])}{', …' * (len(names) > 8)}); "
                        f"choose one: {path}:{names[0]} "
                        f"on the command line, key={names[0]!r} in Python."
                    )
                key = names[0]
            if key not in names:
                raise DataNotFoundError(f"{str(path)!r} has no array {key!r}; it holds: {', '.join(names)}.")
            try:
                array = loaded[key]
            except ValueError as exc:
                if "pickle" not in str(exc).lower():
                    raise InvalidDescriptorsError(f"array {key!r} in {str(path)!r} is not a valid .npy array: "
                                                  f"{str(exc)[:200]}") from exc
                raise InvalidDescriptorsError(
                    f"array {key!r} in {str(path)!r} holds Python objects; btel never unpickles files."
                ) from exc
            except Exception as exc:  # a damaged archive: bad CRC, truncated member, odd compression…
                raise InvalidDescriptorsError(
                    f"{str(path)!r} is a damaged .npz archive; array {key!r} cannot be read "
                    f"({type(exc).__name__}: {str(exc)[:200]})."
                ) from exc
        name = f"{key!r} in {path.name}"
    else:
        if key is not None:
            raise InvalidParameterError(f"key={key!r} only applies to .npz archives; {str(path)!r} is a .npy file.")
        array = loaded
        name = f"descriptors in {path.name}"
        if (isinstance(array, np.memmap) and array.ndim == 2 and array.dtype.kind in "biuf" and array.size
                and not (array.dtype == np.float32 and array.flags.c_contiguous)):
            array = _mapped_as_float32(array, path)
    return check_descriptors(array, name=name)


def _starts_as_pickle(path: Path) -> bool:
    """True when ``path`` starts as a pickle (byte 0x80, then protocol 2 to 5) or as a .npy file (whose
    objects numpy would unpickle) does."""
    try:
        with open(path, "rb") as fh:
            head = fh.read(6)
    except OSError:
        return False
    return head == b"\x93NUMPY" or (len(head) >= 2 and head[0] == 0x80 and 2 <= head[1] <= 5)


def _open_mapped(path: Path, mmap_mode: str | None) -> Any:
    """``np.load(path, mmap_mode=…)`` without pickles; every numpy failure becomes
    :class:`InvalidDescriptorsError`."""
    try:
        return np.load(path, mmap_mode=mmap_mode, allow_pickle=False)
    except ValueError as exc:
        if "pickle" in str(exc).lower() and not _starts_as_pickle(path):  # numpy says "pickle" for any non-.npy
            refuse_text_matrix(path, "descriptor file")  # a text matrix: the command that converts it
            raise InvalidDescriptorsError(
                f"{str(path)!r} is not a .npy file (it does not start with NumPy's header); btel reads .npy, .npz, "
                "hloc .h5 and folders of .npy shards."
            ) from exc
        if "pickle" in str(exc).lower():
            raise InvalidDescriptorsError(
                f"{str(path)!r} holds Python objects (a pickled array); btel never unpickles files because "
                "that can run code. Save the descriptors as a numeric array: np.save(path, X.astype('float32'))."
            ) from exc
        raise InvalidDescriptorsError(f"{str(path)!r} is not a valid .npy file: {exc}") from exc
    except Exception as exc:  # OSError, EOFError, BadZipFile, zlib.error, tokenize's TokenError…: a bad file
        raise InvalidDescriptorsError(
            f"{str(path)!r} is not a readable .npy/.npz file ({type(exc).__name__}: {str(exc)[:200]})."
        ) from exc
