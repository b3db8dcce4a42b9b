"""Which map a model was fitted on: the SHA-256 of the map's rows, kept in the model file's header.

A model's place indices mean something only with the map it was fitted on. :func:`map_fingerprint`
digests the rows as they were fitted — float32, little-endian, one row after another (C order) — so
the same rows give the same digest whatever file held them (``.npy``, ``.h5``, a folder of shards)::

    hashlib.sha256(np.ascontiguousarray(X, dtype="<f4")).hexdigest()

``btel info`` shows it; ``btel evaluate --model M --db MAP`` says when M was fitted on other rows than
MAP. The header is not read by inference, so the digest costs no stored bytes (:mod:`btel.core.storage`).
"""

from __future__ import annotations

import hashlib
import re
from typing import Any

import numpy as np

from ..exceptions import ModelFileError

__all__ = ["map_fingerprint", "read_fingerprint", "describe_fingerprint", "same_map", "feed_file", "file_record"]

#: Bytes of rows converted and digested at a time (a memory-mapped map is read once, never copied whole).
_BLOCK_BYTES = 16 << 20
_HEX64 = re.compile(r"[0-9a-f]{64}\Z")
_FILE_CHUNK = 1 << 20


def feed_file(path: Any, digest: Any) -> int:
    """Feed a regular file's bytes to ``digest`` (a hashlib object), a MiB at a time; its size in bytes."""
    size = 0
    with open(path, "rb") as fh:
        while chunk := fh.read(_FILE_CHUNK):
            digest.update(chunk)
            size += len(chunk)
    return size


def file_record(path: Any) -> dict[str, Any]:
    """``{"bytes", "sha256"}`` of a file: what a record that vouches for the file keeps."""
    digest = hashlib.sha256()
    size = feed_file(path, digest)
    return {"bytes": size, "sha256": digest.hexdigest()}


def map_fingerprint(X: Any) -> dict[str, Any]:
    """``{"rows": n, "dims": d, "sha256": hex}`` of a map of shape (n, d) (any real dtype, read as float32)."""
    X = np.asarray(X) if not hasattr(X, "shape") else X
    n, d = int(X.shape[0]), int(X.shape[1])
    digest = hashlib.sha256()
    step = max(1, _BLOCK_BYTES // max(1, 4 * d))
    for start in range(0, n, step):
        digest.update(np.ascontiguousarray(X[start:start + step], dtype="<f4"))
    return {"rows": n, "dims": d, "sha256": digest.hexdigest()}


def same_map(recorded: dict[str, Any] | None, X: Any) -> bool | None:
    """Whether ``X`` holds the rows a ``recorded`` fingerprint digests (None: nothing recorded)."""
    if recorded is None:
        return None
    if (recorded["rows"], recorded["dims"]) != (int(X.shape[0]), int(X.shape[1])):
        return False
    return map_fingerprint(X)["sha256"] == recorded["sha256"]


def read_fingerprint(value: Any) -> dict[str, Any] | None:
    """The fingerprint of a model file's header, checked (a header is untrusted input).

    None when the file records none (saved before btel recorded it).

    Raises
    ------
    ModelFileError
        Anything but ``{"rows": int ≥ 1, "dims": int ≥ 1, "sha256": 64 lowercase hex digits}``.
    """
    if value is None:
        return None
    ok = (isinstance(value, dict) and set(value) == {"rows", "dims", "sha256"}
          and all(type(value[k]) is int and 1 <= value[k] < 2**63 for k in ("rows", "dims"))
          and isinstance(value["sha256"], str) and _HEX64.match(value["sha256"]) is not None)
    if not ok:
        raise ModelFileError("the header's map fingerprint is malformed (want rows, dims and a sha256 of 64 hex "
                             "digits); the file is corrupt or was edited.")
    return dict(value)


def describe_fingerprint(recorded: dict[str, Any] | None) -> str:
    """``3,576 rows × 3,780 values, sha256 1a2b3c4d5e6f7a8b…`` (or why it is not known)."""
    if recorded is None:
        return "not recorded (a model file saved before btel recorded its map)"
    return f"{recorded['rows']:,d} rows × {recorded['dims']:,d} values, sha256 {recorded['sha256'][:16]}…"
