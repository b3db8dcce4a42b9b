"""Weights stored at 32, 16, 8 or 4 bits, with one scale per row (per code column).

A (K, d') float matrix W is stored as

- 32 bits: the float32 values themselves (no scales);
- 16 / 8 bits: signed integers q = round(W_k / s_k) in [−q_max, q_max], int16 / int8, with
  s_k = max_j |W_kj| / q_max (float32, one per row), q_max = 2^(bits−1) − 1;
- 4 bits: the same with q_max = 7, two values per byte (uint8, shape (K, ⌈d'/2⌉)): column 2j in
  the low nibble and 2j + 1 in the high nibble, two's complement; an odd d' pads one zero nibble.

Symmetric, no clipping: the largest weight of a row is represented exactly (|q| = q_max), so
quantising the dequantised matrix again with the same scales gives the same integers (the round
trip the tests check), and a model file holds exactly the stored integers and scales (bitwise).
Why max-abs and not an error-minimising clip: at 4 bits the recall of the code decoders on
Gardens Point and synthetic routes was the same as at 32 bits within noise (``btel experiment codes``),
so there was nothing for a cleverer scale to win.

The bytes are ``K·d'·4`` (32 bits), ``K·d'·2 + 4K`` (16), ``K·d' + 4K`` (8) and ``K·⌈d'/2⌉ + 4K`` (4):
:func:`weight_specs` lists the arrays, and the storage rule sums their ``nbytes``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..base import ArraySpec
from ...exceptions import InvalidParameterError, ModelFileError

__all__ = ["WEIGHT_BITS", "QuantisedWeights", "quantise", "pack_nibbles", "unpack_nibbles", "weight_specs",
           "weight_bytes"]

WEIGHT_BITS = (32, 16, 8, 4)
_INT_DTYPES = {16: np.dtype(np.int16), 8: np.dtype(np.int8), 4: np.dtype(np.uint8)}


def _qmax(bits: int) -> int:
    return (1 << (bits - 1)) - 1


def _check_bits(bits: int) -> int:
    if bits not in WEIGHT_BITS:
        raise InvalidParameterError(f"weight bits must be one of {WEIGHT_BITS}; got {bits!r}.")
    return int(bits)


def pack_nibbles(values: np.ndarray) -> np.ndarray:
    """Two signed 4-bit values per byte.

    Parameters
    ----------
    values : ndarray of shape (K, d'), integers in [−8, 7]

    Returns
    -------
    ndarray of shape (K, ⌈d'/2⌉), uint8 — column 2j in the low nibble, 2j + 1 in the high one
    """
    v = np.asarray(values)
    if v.size and (int(v.min()) < -8 or int(v.max()) > 7):
        raise InvalidParameterError("4-bit values must lie in [−8, 7].")
    k, d = v.shape
    nibbles = np.zeros((k, d + d % 2), dtype=np.uint8)
    nibbles[:, :d] = (v.astype(np.int16) & 0xF).astype(np.uint8)
    return (nibbles[:, 0::2] | (nibbles[:, 1::2] << 4)).astype(np.uint8)


def unpack_nibbles(packed: np.ndarray, n_columns: int) -> np.ndarray:
    """Inverse of :func:`pack_nibbles`: (K, ⌈d'/2⌉) uint8 → (K, d') int8 in [−8, 7]."""
    p = np.asarray(packed, dtype=np.uint8)
    both = np.empty((p.shape[0], 2 * p.shape[1]), dtype=np.int8)
    both[:, 0::2] = (p & 0xF).astype(np.int8)
    both[:, 1::2] = (p >> 4).astype(np.int8)
    both[both > 7] -= 16  # two's complement of the nibble
    return both[:, :n_columns]


def weight_specs(n_rows: int, n_columns: int, bits: int) -> dict[str, ArraySpec]:
    """Shape and dtype of the stored arrays ``weights`` (and ``scales`` below 32 bits)."""
    bits = _check_bits(bits)
    if bits == 32:
        return {"weights": ArraySpec((n_rows, n_columns), np.float32)}
    width = -(-n_columns // 2) if bits == 4 else n_columns
    return {"weights": ArraySpec((n_rows, width), _INT_DTYPES[bits]), "scales": ArraySpec((n_rows,), np.float32)}


def weight_bytes(n_rows: int, n_columns: int, bits: int) -> int:
    """Bytes of the stored weights and scales of a (K, d') matrix at ``bits``."""
    return int(sum(spec.nbytes for spec in weight_specs(n_rows, n_columns, bits).values()))


@dataclass(frozen=True)
class QuantisedWeights:
    """A (K, d') weight matrix as stored.

    Attributes
    ----------
    values : ndarray
        float32 (K, d') at 32 bits; int16 / int8 (K, d'); uint8 (K, ⌈d'/2⌉) packed at 4 bits.
    scales : ndarray of shape (K,), float32, or None (32 bits)
    bits : int
    n_columns : int
        d'.
    """

    values: np.ndarray
    scales: np.ndarray | None
    bits: int
    n_columns: int

    @property
    def shape(self) -> tuple[int, int]:
        return int(self.values.shape[0]), int(self.n_columns)

    def integers(self) -> np.ndarray:
        """The stored integers, (K, d') int16/int8 (4 bits unpacked); the float32 values at 32 bits."""
        if self.bits == 4:
            return unpack_nibbles(self.values, self.n_columns)
        return self.values

    def dequantise(self) -> np.ndarray:
        """The weights as used at inference, (K, d') float32 (``q·s``)."""
        if self.bits == 32:
            return self.values.astype(np.float32, copy=True)
        with np.errstate(over="ignore", invalid="ignore"):  # an infinite scale: check_fitted_weights names it
            return self.integers().astype(np.float32) * self.scales[:, None]

    def arrays(self) -> dict[str, np.ndarray]:
        """The stored arrays (``weights``, and ``scales`` below 32 bits)."""
        return {"weights": self.values} if self.scales is None else {"weights": self.values, "scales": self.scales}

    @classmethod
    def from_arrays(cls, arrays: dict[str, np.ndarray], bits: int, n_columns: int) -> "QuantisedWeights":
        """From a model file's (shape-checked) arrays; NaN/inf values or scales ≤ 0 raise ModelFileError."""
        values = arrays["weights"]
        scales = arrays.get("scales") if bits != 32 else None
        if bits == 32 and not np.isfinite(values).all():
            raise ModelFileError("the model file's weights contain NaN or infinite values.")
        if scales is not None and not (np.isfinite(scales).all() and (scales > 0).all()):
            raise ModelFileError("the model file's weight scales must be finite and positive.")
        q = cls(values, scales, int(bits), int(n_columns))
        if bits in (16, 8) and values.size and int(np.abs(values.astype(np.int32)).max()) > _qmax(bits):
            raise ModelFileError(f"the model file's {bits}-bit weights lie outside ±{_qmax(bits)}.")
        if bits == 4 and values.size and int(np.abs(q.integers().astype(np.int32)).max()) > _qmax(4):
            raise ModelFileError("the model file's 4-bit weights lie outside ±7.")
        return q


def quantise(W: np.ndarray, bits: int, scales: np.ndarray | None = None) -> QuantisedWeights:
    """Store a weight matrix at ``bits`` with one scale per row (module docstring).

    Parameters
    ----------
    W : ndarray of shape (K, d'), float
    bits : {32, 16, 8, 4}
    scales : ndarray of shape (K,), optional
        Use these scales instead of ``max|W_k| / q_max`` (a requantisation).

    Returns
    -------
    QuantisedWeights
    """
    bits = _check_bits(bits)
    W = np.asarray(W, dtype=np.float64)
    if W.ndim != 2 or not np.isfinite(W).all():
        raise InvalidParameterError("weights must be a finite 2-D matrix.")
    if bits == 32:
        return QuantisedWeights(W.astype(np.float32), None, 32, W.shape[1])
    qmax = _qmax(bits)
    if scales is None:
        peak = np.abs(W).max(axis=1) if W.shape[1] else np.zeros(W.shape[0])
        # A row below float32's smallest normal number times q_max has no representable scale: it is
        # stored as zeros (scale 1), an error of at most that peak.
        peak = np.where(peak >= np.finfo(np.float32).tiny * qmax, peak, 0.0)
        with np.errstate(over="ignore"):  # a peak past float32's range: inf here, refused by check_fitted_weights
            scales = np.where(peak > 0, peak / qmax, 1.0).astype(np.float32)
        # A float32 scale rounded down could push the peak to q_max + 1: round it up instead.
        scales = np.where(peak / scales.astype(np.float64) > qmax + 0.5, np.nextafter(scales, np.inf), scales)
    scales = np.asarray(scales, dtype=np.float32)
    q = np.clip(np.rint(W / scales.astype(np.float64)[:, None]), -qmax, qmax).astype(np.int16)
    values = pack_nibbles(q) if bits == 4 else q.astype(_INT_DTYPES[bits])
    return QuantisedWeights(values, scales.astype(np.float32), bits, W.shape[1])
