"""Counter-based hashing for the implicit codebooks: splitmix64, keyed permutations, the random family's bits.

Every number a :class:`~btel.methods.codes.codebook.Codebook` draws comes from here: a pure
function of integer keys evaluated with wrapping uint64 arithmetic, so the same keys give
bit-identical values on every platform and numpy version.

**The random family's generation rules.** A model file records which rule made its codewords
(:data:`RULES`); a file without one was written with :data:`LEGACY_RULE`.

- Rule 1 (per bit): column c of place i is the top bit of splitmix64(i·γ ⊕ key_c), one hash per
  (place, column) — N·K hashes for the whole codebook (4.7·10⁸ at N = 10⁶, K = 470).
- Rule 2 (:data:`CURRENT_RULE`, 64 columns per hash): h_ig = splitmix64(key_g + (i + 1)·γ), the
  (i + 1)-th output of a SplitMix64 generator seeded with group g's key, gives the 64 columns
  64g … 64g + 63: column j is bit j mod 64 of h_{i, j // 64}. So the packed codeword of a place
  (column j in bit j mod 8 of byte j // 8, as ``np.packbits(..., bitorder='little')``) *is* its
  hashes' bytes in little-endian order, cut to ⌈K/8⌉ bytes with the unused high bits of the last
  byte zero: ⌈K/64⌉ hashes per place and no bit packing (:func:`grouped_packed`).

Both draw every bit as an independent fair coin (in expectation: balanced columns, no structure
along the route).
"""

from __future__ import annotations

import math

import sys

import numpy as np

__all__ = ["RULES", "CURRENT_RULE", "LEGACY_RULE", "splitmix", "hash_keys", "keyed_permutation",
           "per_bit_positive", "grouped_packed", "grouped_positive"]

#: Generation rules of the random family: 1 one hash per bit, 2 one hash per 64 columns.
RULES = (1, 2)
#: The rule new codebooks use.
CURRENT_RULE = 2
#: The rule of model files that record none (written before rules were recorded).
LEGACY_RULE = 1

_U64 = np.uint64
GOLDEN = _U64(0x9E3779B97F4A7C15)
_MIX1 = _U64(0xBF58476D1CE4E5B9)
_MIX2 = _U64(0x94D049BB133111EB)
#: Places hashed at a time by :func:`grouped_packed` (8·⌈K/64⌉ bytes each: 4 MB at K = 470).
_GROUP_PLACES = 1 << 16


def splitmix(z: np.ndarray, work: dict | None = None) -> np.ndarray:
    """The splitmix64 finaliser on a uint64 array (wrapping arithmetic), computed in ``z``'s memory (overwritten).

    With ``work`` (:func:`buffer`), only the result's top bit, as bool (the last step, z ^ z >> 31, keeps it).
    """
    z = z if isinstance(z, np.ndarray) else np.asarray(z, dtype=_U64)
    with np.errstate(over="ignore"):
        t = np.right_shift(z, _U64(30), out=buffer(work, "t", z.shape, _U64))
        z ^= t
        z *= _MIX1
        np.right_shift(z, _U64(27), out=t)
        z ^= t
        z *= _MIX2
        if work is not None:
            return np.greater_equal(z, _U64(1 << 63), out=buffer(work, "bool", z.shape, bool))
        np.right_shift(z, _U64(31), out=t)
        z ^= t
    return z


def buffer(work: dict | None, name: str, shape: tuple[int, ...], dtype: type) -> np.ndarray:
    """A view of ``work[name]`` of this shape (grown when too small), or a new array without ``work``: blocks of
    codewords generated in turn reuse their work arrays (fresh megabyte arrays each time cost page faults)."""
    size = math.prod(shape)
    if work is None:
        return np.empty(shape, dtype=dtype)
    if name not in work or work[name].size < size:
        work[name] = np.empty(size, dtype=dtype)
    return work[name][:size].reshape(shape)


def hash_keys(*keys: np.ndarray | int) -> np.ndarray:
    """A 64-bit hash of integer keys (broadcast), as a uint64 array."""
    z = np.zeros((), dtype=_U64)
    with np.errstate(over="ignore"):
        for key in keys:
            z = splitmix(z ^ (np.asarray(key).astype(_U64) + GOLDEN))
    return np.asarray(z, dtype=_U64)


def keyed_permutation(x: np.ndarray, n: int, keys: np.ndarray) -> np.ndarray:
    """π_key(x): a pseudo-random permutation of [0, n) per key, evaluated elementwise.

    A 4-round Feistel network on the smallest even number of bits covering n, with cycle walking
    (values ≥ n are permuted again until they fall below n), so π is a bijection of [0, n) for
    every key and any element can be evaluated alone (no table of n entries).

    Parameters
    ----------
    x : ndarray of int64, values in [0, n)
    n : int
        Domain size ≥ 1.
    keys : ndarray of uint64, broadcastable against x
        One key per permutation.

    Returns
    -------
    ndarray of int64, the shape of ``np.broadcast(x, keys)``
    """
    bits = max(2, int(n - 1).bit_length())
    bits += bits % 2
    half = _U64(bits // 2)
    mask = _U64((1 << (bits // 2)) - 1)
    y, keys = np.broadcast_arrays(np.asarray(x, dtype=np.int64).astype(_U64), np.asarray(keys, dtype=_U64))
    y, keys = y.copy(), np.ascontiguousarray(keys)

    round_keys = [hash_keys(keys, r) for r in range(4)]

    def rounds(v: np.ndarray, todo: np.ndarray | slice) -> np.ndarray:
        left, right = v >> half, v & mask
        for key in round_keys:
            left, right = right, left ^ (splitmix(right ^ key[todo]) & mask)
        return (left << half) | right

    y = rounds(y, slice(None))
    todo = y >= _U64(n)
    while todo.any():
        y[todo] = rounds(y[todo], todo)
        todo = y >= _U64(n)
    return y.astype(np.int64)


def per_bit_positive(places: np.ndarray, keys: np.ndarray, work: dict | None = None) -> np.ndarray:
    """Rule 1: whether column c of each place is +1, the top bit of splitmix64(i·γ ⊕ key_c).

    Parameters
    ----------
    places : ndarray of int64, shape (n,)
    keys : ndarray of uint64, shape (m,)
        The keys of the requested columns.
    work : dict, optional
        Work arrays kept between calls (:func:`buffer`).

    Returns
    -------
    ndarray of shape (n, m), bool (a view of a work array when ``work`` is given)
    """
    shape, work = (places.shape[0], keys.size), {} if work is None else work
    with np.errstate(over="ignore"):
        z = np.bitwise_xor(places.astype(_U64)[:, None] * GOLDEN, keys, out=buffer(work, "z", shape, _U64))
    return splitmix(z, work)


def _group_hashes(places: np.ndarray, keys: np.ndarray) -> np.ndarray:
    """Rule 2's hashes h_ig = splitmix64(key_g + (i + 1)·γ), uint64 (n, number of keys)."""
    with np.errstate(over="ignore"):
        z = ((places.astype(_U64) + _U64(1)) * GOLDEN)[:, None] + keys
    return splitmix(z)


def _little_endian_bytes(h: np.ndarray) -> np.ndarray:
    """The bytes of uint64 hashes (n, g) in little-endian order, uint8 (n, 8g) (a view on little-endian machines)."""
    if sys.byteorder != "little":
        h = h.astype("<u8")
    return h.view(np.uint8)


def grouped_packed(places: np.ndarray, keys: np.ndarray, n_codes: int, out: np.ndarray | None = None) -> np.ndarray:
    """Rule 2: the packed codewords of the given places straight from their hashes (no ±1 signs, no bit packing).

    Parameters
    ----------
    places : ndarray of int64, shape (n,)
    keys : ndarray of uint64, shape (⌈K/64⌉,)
        Every group's key.
    n_codes : int
        K.
    out : ndarray of shape (n, ⌈K/8⌉), uint8, optional
        Written in place (e.g. a view of faiss' code array).

    Returns
    -------
    ndarray of shape (n, ⌈K/8⌉), uint8: column j in bit j % 8 of byte j // 8, the unused high bits
    of the last byte zero (``np.packbits(codewords > 0, axis=1, bitorder='little')``)
    """
    n, width = places.shape[0], -(-int(n_codes) // 8)
    out = np.empty((n, width), dtype=np.uint8) if out is None else out
    for a in range(0, n, _GROUP_PLACES):
        b = min(n, a + _GROUP_PLACES)
        out[a:b] = _little_endian_bytes(_group_hashes(places[a:b], keys))[:, :width]
    if n_codes % 8:
        out[:, width - 1] &= np.uint8((1 << (n_codes % 8)) - 1)
    return out


def grouped_positive(places: np.ndarray, keys: np.ndarray, columns: np.ndarray) -> np.ndarray:
    """Rule 2: whether each requested column of each place is +1, hashing only the groups those columns need.

    Parameters
    ----------
    places : ndarray of int64, shape (n,)
    keys : ndarray of uint64, shape (⌈K/64⌉,)
    columns : ndarray of int64, shape (m,), values in [0, K)

    Returns
    -------
    ndarray of shape (n, m), uint8 in {0, 1}
    """
    groups, where = np.unique(columns >> 6, return_inverse=True)
    bits = np.unpackbits(_little_endian_bytes(_group_hashes(places, keys[groups])), axis=1, bitorder="little")
    if columns.size and np.all(np.diff(columns) == 1):  # a run of consecutive columns (all K): no gather
        start = int(columns[0]) - 64 * int(groups[0])
        return bits[:, start : start + columns.size]
    return bits[:, where.reshape(-1) * 64 + (columns & 63)]
