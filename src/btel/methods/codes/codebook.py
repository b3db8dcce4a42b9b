"""Output codes of the places: K ±1 columns per place, regenerated from (family, N, K, seed), never stored.

BTEL's tree code is the smallest member of the error-correcting output codes (Dietterich & Bakiri
1995): place i gets a codeword c_i ∈ {−1, +1}^K, one linear model per column predicts it, and a
query is decoded to the place whose codeword agrees best with the K predicted scores
(:mod:`btel.methods.codes.estimator`). The codewords here are *implicit*: a pure function of the
place index, the family, N, K and a seed, so a model stores its K·d' weights and no codebook (0
bytes; the family, K and seed are in the model header), and :meth:`Codebook.codewords` regenerates
any rows on demand — in chunks, so a million places × K columns is never held at once.

Families (``c_ik`` is column k of place i):

- ``binary`` — the paper's BTE-C code, K = b = ⌈log2 N⌉: column j is bit j (MSB first) of i,
  +1 for a 1 bit (:func:`btel.methods.btel.compressed.code_signs` with one copy).
- ``offset`` — BTE-C's offset codes: the first K columns of the BTE-C code with the fewest copies m
  that has at least K columns (:func:`btel.methods.btel.compressed.compressed_code`); at most
  ``max_columns('offset', N)`` distinct columns exist (m ≤ 256).
- ``periodic`` — multi-scale square waves in quadrature pairs: frequency h has period
  P_h = exp(log 4 + u_h·(log P_max − log 4)), P_max = max(N, 8), with u_h stratified in
  [h/H, (h+1)/H) (H = ⌈K/2⌉ frequencies, a jitter per stratum from the seed) and a phase φ_h ∈ [0, 1);
  column 2h is sign cos(2π(i/P_h + φ_h)) and column 2h+1 sign sin(2π(i/P_h + φ_h)), evaluated in
  64-bit fixed point (i·F_h + Φ_h mod 2^64, exact integer arithmetic). Neighbouring
  places share most of their codeword (errors stay local), and the quadrature pair makes the
  code's kernel E[c_i·c_j] a function of |i − j| only. Stratified periods and quadrature pairs
  approximate that kernel with fewer columns than independent draws.
- ``blocks`` — random contiguous-block codes at many scales: column k cuts the route into blocks of
  L_k places (log-uniform stratified in [1, N/8], so at least 8 blocks) at a random offset, and
  colours exactly half of the blocks +1 (a keyed permutation of the blocks). L = 1 is a random code;
  long blocks are BTE-C-like splits with random boundaries. E[c_i·c_j] ≈ max(0, 1 − |i − j|/L)
  averaged over scales.
- ``random`` — random codes: every (place, column) bit is an independent fair coin (bits of a
  counter-based hash: one hash per 64 columns of a place, or one per bit under the rule of older
  model files; :mod:`btel.methods.codes.hashing`), so columns are balanced in expectation (within
  about ±√N/2 places; ``docs/decisions/codes-families.md`` says why not exactly) and neighbouring
  places share nothing. No route structure: for maps of independent places rather than a route.

Every number drawn from the seed comes from a counter-based hash (splitmix64 of seed, family,
column, stream), not from a stateful generator, and every code is evaluated with exact integer or
IEEE double arithmetic (no libm), so the same (family, N, K, seed, rule) gives bit-identical
codewords on every platform and numpy version.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field
from typing import Iterator

import numpy as np

from ..btel.compressed import compressed_code, compressed_n_classifiers
from ..btel.encoding import n_bits_for
from ...exceptions import InvalidParameterError
from .hashing import (CURRENT_RULE, RULES, grouped_packed, grouped_positive, hash_keys,
                      keyed_permutation, per_bit_positive)
from .periodic import periodic_counts, periodic_packed_run, periodic_positive

__all__ = ["FAMILIES", "ROUTE_FAMILIES", "Codebook", "max_columns", "keyed_permutation", "hash_uniform"]

FAMILIES = ("binary", "offset", "periodic", "blocks", "random")
#: Families whose neighbouring places share most of their codeword (the coarse decode relies on it).
ROUTE_FAMILIES = ("binary", "offset", "periodic", "blocks")
#: Most columns of the families that can have any number (periodic, blocks, random).
MAX_COLUMNS = 65536
#: Most offset-code copies (as ``BTELocalizer.code_copies``).
MAX_OFFSET_COPIES = 256
#: Shortest period of the periodic family (shorter square waves alias on integer places).
MIN_PERIOD = 4.0

_U64 = np.uint64
#: Stream ids keep the numbers drawn for different purposes independent.
_STREAMS = {"period": 1, "phase": 2, "scale": 3, "offset": 4, "permutation": 5}
_FAMILY_IDS = {name: i + 1 for i, name in enumerate(FAMILIES)}
#: Elements (rows × columns) generated at a time by :meth:`Codebook.iter_blocks` (uint64 work arrays of 4 MB).
_BLOCK_ELEMENTS = 1 << 19
#: Shortest block whose periodic sums :meth:`Codebook.block_sums` counts in closed form
#: (shorter: summing is as fast).
_CLOSED_FORM_BLOCK = 8


def hash_uniform(seed: int, family: str, stream: str, index: np.ndarray) -> np.ndarray:
    """Uniform numbers in [0, 1) that depend only on (seed, family, stream, index), float64."""
    z = hash_keys(int(seed), _FAMILY_IDS[family], _STREAMS[stream], np.asarray(index, dtype=np.int64))
    return (z >> _U64(11)).astype(np.float64) * (1.0 / (1 << 53))


@functools.lru_cache(maxsize=256)
def _offset_copies(n_places: int, n_codes: int) -> int:
    """Fewest copies m whose BTE-C offset code has at least ``n_codes`` columns."""
    for m in range(1, MAX_OFFSET_COPIES + 1):
        if compressed_n_classifiers(n_places, m) >= n_codes:
            return m
    raise InvalidParameterError(
        f"the offset family has at most {max_columns('offset', n_places)} distinct columns for "
        f"N = {n_places}; "
        f"got n_codes = {n_codes}. Use fewer codes or the periodic family."
    )


def max_columns(family: str, n_places: int) -> int:
    """Most columns K a family can have for N places (binary: exactly b)."""
    if family == "binary":
        return n_bits_for(n_places)
    if family == "offset":
        return compressed_n_classifiers(n_places, MAX_OFFSET_COPIES)
    return MAX_COLUMNS


def min_columns(family: str, n_places: int) -> int:
    """Fewest columns K of a family: b = ⌈log2 N⌉ (fewer cannot tell N places apart)."""
    return n_bits_for(n_places)


@dataclass(frozen=True)
class Codebook:
    """The implicit codewords of N places: K ±1 columns of one family, a pure function of its fields.

    Parameters
    ----------
    family : {'binary', 'offset', 'periodic', 'blocks', 'random'}
    n_places : int
        N ≥ 2.
    n_codes : int
        K, in [b, :func:`max_columns`] (binary: exactly b = ⌈log2 N⌉).
    seed : int
        ≥ 0; unused by binary and offset.
    rule : int
        The random family's generation rule (:mod:`btel.methods.codes.hashing`): 2 (default) one
        hash per 64 columns, 1 one hash per bit (model files that record no rule). The other
        families' codewords are the same under every rule: they record the current one.

    Examples
    --------
    >>> book = Codebook("periodic", n_places=1000, n_codes=64, seed=0)
    >>> book.codewords(np.array([0, 999])).shape
    (2, 64)
    """

    family: str
    n_places: int
    n_codes: int
    seed: int = 0
    rule: int = CURRENT_RULE
    _params: dict = field(default_factory=dict, init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        if self.family not in FAMILIES:
            raise InvalidParameterError(f"code family must be one of {FAMILIES}; got {self.family!r}.")
        n, k = int(self.n_places), int(self.n_codes)
        if n < 2:
            raise InvalidParameterError(f"a codebook needs N ≥ 2 places; got {n}.")
        low, high = min_columns(self.family, n), max_columns(self.family, n)
        if self.family == "binary" and k != low:
            raise InvalidParameterError(
                f"the binary family has exactly b = {low} columns for N = {n}; got {k}.")
        if not low <= k <= high:
            raise InvalidParameterError(
                f"the {self.family} family takes K in [{low}, {high}] columns for N = {n}; got {k}.")
        if int(self.seed) < 0:
            raise InvalidParameterError(f"the code seed must be ≥ 0; got {self.seed}.")
        if (isinstance(self.rule, bool) or not isinstance(self.rule, (int, np.integer))
                or self.rule not in RULES):
            raise InvalidParameterError(f"the code rule must be one of {RULES}; got {self.rule!r}.")
        object.__setattr__(self, "rule", int(self.rule) if self.family == "random" else CURRENT_RULE)
        object.__setattr__(self, "_params", self._column_parameters())

    # -- column parameters --------------------------------------------------------------------
    def _column_parameters(self) -> dict[str, np.ndarray]:
        n, k, seed = int(self.n_places), int(self.n_codes), int(self.seed)
        if self.family in ("binary", "offset"):
            levels, shifts = compressed_code(n, 1 if self.family == "binary" else _offset_copies(n, k))
            b = n_bits_for(n)
            return {"low_bit": (b - 1 - levels[:k]).astype(np.int64), "shift": shifts[:k].astype(np.int64),
                    "modulus": np.int64(1 << b), "length": (1 << (b - 1 - levels[:k])).astype(np.float64)}
        if self.family == "periodic":
            h_count = -(-k // 2)
            h = np.arange(h_count)
            u = (h + hash_uniform(seed, self.family, "period", h)) / h_count
            longest = max(float(n), 2 * MIN_PERIOD)
            period = np.exp(np.log(MIN_PERIOD) + u * (np.log(longest) - np.log(MIN_PERIOD)))
            column = np.arange(k)
            # Phase as a 64-bit fixed-point fraction of a period: t_i = i·F + Φ (mod 2^64) is exact
            # integer arithmetic, and s(t) = +1 on the first half period is t's top bit being 0.
            # Column 2h is the cos wave of frequency h (phase + 1/4 period), column 2h + 1 the sin wave.
            frequency = np.floor((1.0 / period) * 2.0**64).astype(np.uint64)[column // 2]
            phase = hash_keys(seed, _FAMILY_IDS["periodic"], _STREAMS["phase"], h)[column // 2]
            with np.errstate(over="ignore"):
                phase = phase + np.where(column % 2 == 0, _U64(1 << 62), _U64(0))
            return {"frequency": frequency, "phase": phase, "length": period[column // 2] / 2}
        column = np.arange(k)
        if self.family == "blocks":
            u = (column + hash_uniform(seed, self.family, "scale", column)) / k
            # At least 8 blocks per column, so that colouring half of them balances the places too.
            longest = max(n // 8, 1)
            length = np.maximum(1, np.round(np.exp(u * np.log(longest)))).astype(np.int64)
            offset = np.floor(hash_uniform(seed, self.family, "offset", column) * length).astype(np.int64)
            n_blocks = (n - 1 + offset) // length + 1
            return {"block": length, "offset": offset, "n_blocks": n_blocks,
                    "key": hash_keys(seed, _FAMILY_IDS["blocks"], column),
                    "length": length.astype(np.float64)}
        if self.rule == 1:  # a key per column
            return {"key": hash_keys(seed, _FAMILY_IDS["random"], column), "length": np.ones(k)}
        # A key per group of 64 columns (another key chain than rule 1's).
        return {"group_key": hash_keys(seed, _FAMILY_IDS["random"], self.rule, np.arange(-(-k // 64))),
                "length": np.ones(k)}

    def column_lengths(self) -> np.ndarray:
        """Typical run of equal values along the route per column (half a period, a block), float64 (K,)."""
        return self._params["length"].copy()

    # -- codewords ------------------------------------------------------------------------------
    def codewords(self, places: np.ndarray, columns: np.ndarray | slice | None = None,
                  work: dict | None = None) -> np.ndarray:
        """±1 codewords of the given places.

        Parameters
        ----------
        places : array-like of int, shape (n,), values in [0, N)
        columns : index array or slice, optional
            Only these columns (default all K).
        work : dict, optional
            Work arrays kept between calls (:meth:`iter_blocks` passes one), so that generating
            many blocks allocates them once.

        Returns
        -------
        ndarray of shape (n, n_columns), int8 in {−1, +1}
        """
        i = np.asarray(places, dtype=np.int64).reshape(-1, 1)
        if i.size and (int(i.min()) < 0 or int(i.max()) >= self.n_places):
            raise InvalidParameterError(f"place indices must lie in [0, {self.n_places}).")
        sel = slice(None) if columns is None else columns
        if self.family == "random" and self.rule != 1:
            # One hash per (place, group of 64 columns): only the groups the columns need.
            positive = grouped_positive(i[:, 0], self._params["group_key"], np.arange(self.n_codes)[sel])
            out = positive.view(np.int8) * np.int8(2)
            out -= np.int8(1)
            return out
        p = {key: (value[sel] if isinstance(value, np.ndarray) and value.ndim == 1 else value)
             for key, value in self._params.items()}
        if self.family in ("binary", "offset"):
            positive = ((((i + p["shift"]) % p["modulus"]) >> p["low_bit"]) & 1).astype(bool)
        elif self.family == "periodic":
            positive = periodic_positive(i, p["frequency"], p["phase"], work)
        elif self.family == "blocks":
            positive = self._block_colours(i[:, 0], p)
        else:  # random, rule 1: one hash per (place, column)
            positive = per_bit_positive(i[:, 0], p["key"], work)
        out = positive.view(np.int8) * np.int8(2)
        out -= np.int8(1)
        return out

    def packed(self, places: np.ndarray, out: np.ndarray | None = None,
               work: dict | None = None) -> np.ndarray:
        """Packed codewords of the given places: +1 → bit 1, column j in bit j % 8 of byte j // 8,
        unused high bits of the last byte 0
        (``np.packbits(codewords(places) > 0, axis=1, bitorder='little')``).

        The random family's current rule writes its hashes' bytes
        (:func:`~btel.methods.codes.hashing.grouped_packed`): no ±1 codewords and no bit packing.

        Parameters
        ----------
        places : array-like of int, shape (n,), values in [0, N)
        out : ndarray of shape (n, ⌈K/8⌉), uint8, optional
            Written in place.
        work : dict, optional
            Work arrays kept between calls (as :meth:`codewords`), for callers that fill many blocks.

        Returns
        -------
        ndarray of shape (n, ⌈K/8⌉), uint8
        """
        i = np.asarray(places, dtype=np.int64).reshape(-1)
        if self.family == "random" and self.rule != 1:
            if i.size and (int(i.min()) < 0 or int(i.max()) >= self.n_places):
                raise InvalidParameterError(f"place indices must lie in [0, {self.n_places}).")
            return grouped_packed(i, self._params["group_key"], self.n_codes, out=out)
        out = np.empty((i.size, -(-self.n_codes // 8)), dtype=np.uint8) if out is None else out
        rows, work = max(1, _BLOCK_ELEMENTS // max(self.n_codes, 1)), {} if work is None else work
        periodic = self.family == "periodic"
        if periodic and i.size and (int(i.min()) < 0 or int(i.max()) >= self.n_places):
            raise InvalidParameterError(f"place indices must lie in [0, {self.n_places}).")
        if periodic and i.size > 1 and i[-1] - i[0] == i.size - 1 and bool((np.diff(i) == 1).all()):
            return periodic_packed_run(self._params["frequency"], self._params["phase"], int(i[0]), i.size,
                                       out, work)
        for a in range(0, i.size, rows):
            if periodic:  # the signs' bits straight from the phases: no ±1 codewords in between
                positive = periodic_positive(i[a : a + rows, None], self._params["frequency"],
                                              self._params["phase"], work)
            else:
                positive = self.codewords(i[a : a + rows], work=work) > 0
            out[a : a + rows] = np.packbits(positive, axis=1, bitorder="little")
        return out

    @staticmethod
    def _block_colours(places: np.ndarray, p: dict[str, np.ndarray]) -> np.ndarray:
        """+1 where the place's block is in the upper half of a keyed permutation of the column's blocks.

        Exactly half of each column's blocks are +1. The permutation is evaluated once per block
        present (not per place), then spread over the places.
        """
        out = np.empty((places.size, p["block"].size), dtype=bool)
        if places.size == 0:
            return out
        lo, hi = int(places.min()), int(places.max())
        for c in range(p["block"].size):
            length, offset, n_blocks = int(p["block"][c]), int(p["offset"][c]), int(p["n_blocks"][c])
            first = (lo + offset) // length
            ids = np.arange(first, (hi + offset) // length + 1)
            colours = keyed_permutation(ids, n_blocks, p["key"][c]) >= n_blocks // 2
            out[:, c] = colours[(places + offset) // length - first]
        return out

    def iter_blocks(self, start: int = 0, stop: int | None = None,
                    rows: int | None = None) -> Iterator[tuple[int, int, np.ndarray]]:
        """Yield (start, stop, codewords of places start:stop) over consecutive blocks of places.

        ``rows`` places per block (default: about 0.5 M values per block), so the whole (N, K)
        codebook is never held at once.
        """
        stop = self.n_places if stop is None else stop
        rows = rows or max(1, _BLOCK_ELEMENTS // max(self.n_codes, 1))
        work: dict = {}
        for a in range(start, stop, rows):
            b = min(stop, a + rows)
            yield a, b, self.codewords(np.arange(a, b), work=work)

    def block_signs(self, block: int) -> np.ndarray:
        """Per block of ``block`` consecutive places: +1 / −1 where a column is constant on it, 0 where
        it varies.

        The blocks are places [j·B, min(N, (j + 1)·B)). The periodic family is answered in closed form
        from its fixed-point phases (no codeword is generated: milliseconds at N = 10⁶): column k is
        constant on a block of L places starting at phase t iff t's offset in its half period plus
        (L − 1)·F_k stays below 2⁶³. Other families take the block minima and maxima of their codewords.

        Returns
        -------
        ndarray of shape (⌈N/B⌉, K), int8 in {−1, 0, +1}
        """
        n, block = int(self.n_places), int(block)
        if block < 1:
            raise InvalidParameterError(f"block must be ≥ 1; got {block}.")
        starts = np.arange(0, n, block, dtype=np.int64)
        if self.family == "periodic":
            p = self._params
            lengths = np.minimum(block, n - starts).astype(_U64)[:, None]
            with np.errstate(over="ignore"):
                t = starts.astype(_U64)[:, None] * p["frequency"] + p["phase"]
                half = _U64(1 << 63)
                # (L − 1)·F < 2⁶³ without overflow: L − 1 ≤ (2⁶³ − 1) // F.
                short = (lengths - _U64(1)) <= (half - _U64(1)) // p["frequency"]
                span = np.where(short, (lengths - _U64(1)) * p["frequency"], _U64(0))
                constant = short & ((t & (half - _U64(1))) + span < half)
            out = np.where(t < half, np.int8(1), np.int8(-1)).astype(np.int8)
            out[~constant] = 0
            return out
        out = np.empty((starts.size, self.n_codes), dtype=np.int8)
        rows = max(block, (_BLOCK_ELEMENTS // max(self.n_codes, 1)) // block * block)
        for a, b, codes in self.iter_blocks(rows=rows):  # a is a multiple of block
            firsts = np.arange(0, b - a, block)
            low = np.minimum.reduceat(codes, firsts, axis=0)
            high = np.maximum.reduceat(codes, firsts, axis=0)
            out[a // block : a // block + firsts.size] = np.where(low == high, low, 0)
        return out

    def block_sums(self, block: int) -> np.ndarray:
        """Per block of ``block`` consecutive places: the sum of its ±1 codewords (B × its mean codeword).

        The blocks are places [j·B, min(N, (j + 1)·B)). The periodic family is counted in closed form
        (:func:`~btel.methods.codes.periodic.periodic_counts`); the other families sum their int8
        codewords block by block.

        Returns
        -------
        ndarray of shape (⌈N/B⌉, K), int32
        """
        n, block = int(self.n_places), int(block)
        if block < 1:
            raise InvalidParameterError(f"block must be ≥ 1; got {block}.")
        n_blocks, whole = -(-n // block), n // block  # whole: the blocks of exactly B places
        out = np.empty((n_blocks, self.n_codes), dtype=np.int32)
        if self.family == "periodic" and block >= _CLOSED_FORM_BLOCK and whole:
            counts = periodic_counts(self._params["frequency"], self._params["phase"], block, whole)
            out[:whole] = 2 * counts - block
            if whole < n_blocks:  # the shorter last block
                out[whole] = self.codewords(np.arange(whole * block, n)).sum(axis=0, dtype=np.int32)
            return out
        rows = max(block, (_BLOCK_ELEMENTS // max(self.n_codes, 1)) // block * block)
        for a, b, codes in self.iter_blocks(rows=rows):  # a is a multiple of block
            full, j = (b - a) // block, a // block
            whole = codes[: full * block].reshape(full, block, self.n_codes)
            out[j : j + full] = whole.sum(axis=1, dtype=np.int32)
            if full * block < b - a:  # the shorter last block
                out[j + full] = codes[full * block :].sum(axis=0, dtype=np.int32)
        return out

    def to_header(self) -> dict[str, int | str]:
        """What a model file records to regenerate this codebook."""
        return {"family": self.family, "n_places": int(self.n_places), "n_codes": int(self.n_codes),
                "seed": int(self.seed), "rule": int(self.rule)}
