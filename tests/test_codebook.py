"""Implicit codewords: a pure function of (family, N, K, seed), identical however they are generated."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from btel.methods.codes.codebook import FAMILIES, Codebook, keyed_permutation, max_columns, min_columns
from btel.methods.btel.compressed import code_signs, compressed_n_classifiers
from btel.exceptions import InvalidParameterError

FREE = ("periodic", "blocks", "random")


@pytest.mark.parametrize("n_places", [2, 3, 5, 200, 1000, 1025])
def test_binary_and_offset_reproduce_bte_c_columns(n_places: int) -> None:
    b = min_columns("binary", n_places)
    np.testing.assert_array_equal(Codebook("binary", n_places, b).codewords(np.arange(n_places)),
                                  code_signs(n_places, 1))
    for copies in (2, 3, 4, 8):
        k = compressed_n_classifiers(n_places, copies)
        np.testing.assert_array_equal(Codebook("offset", n_places, k).codewords(np.arange(n_places)),
                                      code_signs(n_places, copies))


@settings(max_examples=30, deadline=None)
@given(family=st.sampled_from(FAMILIES), n_places=st.integers(2, 1500), k=st.integers(1, 48),
       seed=st.integers(0, 2**32 - 1), data=st.data())
def test_codewords_regenerate_identically_in_any_order_and_chunking(family, n_places, k, seed, data) -> None:
    k = min(max(k, min_columns(family, n_places)), max_columns(family, n_places))
    if family == "binary":
        k = min_columns(family, n_places)
    book = Codebook(family, n_places, k, seed)
    places = np.asarray(data.draw(st.lists(st.integers(0, n_places - 1), min_size=1, max_size=50)))
    codes = book.codewords(places)
    assert codes.dtype == np.int8 and codes.shape == (places.size, k)
    assert set(np.unique(codes)) <= {-1, 1}
    # A fresh codebook from the recorded header, and the rows one at a time, give the same codewords.
    again = Codebook(**book.to_header())
    np.testing.assert_array_equal(again.codewords(places), codes)
    np.testing.assert_array_equal(np.concatenate([book.codewords(places[i : i + 1]) for i in range(places.size)]),
                                  codes)
    full = np.concatenate([c for _, _, c in book.iter_blocks(rows=data.draw(st.integers(1, 700)))])
    np.testing.assert_array_equal(full[places], codes)
    cols = np.asarray(data.draw(st.lists(st.integers(0, k - 1), min_size=1, max_size=k)))
    np.testing.assert_array_equal(book.codewords(places, cols), codes[:, cols])


def test_codewords_are_pinned_across_versions() -> None:
    """A change to the generators would silently change every saved model's decode: pin a few values."""
    pinned = {}
    for family, rule in [(family, 2) for family in FREE] + [("random", 1)]:
        codes = Codebook(family, 10_000, 16, seed=7, rule=rule).codewords(np.array([0, 1, 2, 4999, 9999]))
        pinned[family if rule == 2 else f"{family} rule {rule}"] = int(((codes > 0).astype(np.int64) * (1 << np.arange(16))).sum())
    assert pinned == PINNED, pinned


#: 'random rule 1' is the value pinned before generation rules were recorded (files without a rule use it).
PINNED = {"periodic": 215102, "blocks": 203311, "random": 202438, "random rule 1": 165943}


@settings(max_examples=60, deadline=None)
@given(n=st.integers(1, 5000), key=st.integers(0, 2**64 - 1))
def test_keyed_permutation_is_a_bijection(n: int, key: int) -> None:
    image = keyed_permutation(np.arange(n), n, np.uint64(key))
    np.testing.assert_array_equal(np.sort(image), np.arange(n))


def test_blocks_colour_exactly_half_of_each_columns_blocks() -> None:
    book = Codebook("blocks", 5000, 64, seed=3)
    codes = book.codewords(np.arange(5000))
    params = book._params
    for c in range(64):
        block_ids = (np.arange(5000) + params["offset"][c]) // params["block"][c]
        first = np.unique(block_ids, return_index=True)[1]
        n_blocks = int(params["n_blocks"][c])
        assert first.size == n_blocks
        assert int((codes[first, c] > 0).sum()) == n_blocks - n_blocks // 2
        # Constant within a block.
        assert all(np.unique(codes[block_ids == b, c]).size == 1 for b in np.unique(block_ids)[:5])


def test_periodic_columns_are_square_waves_in_quadrature() -> None:
    book = Codebook("periodic", 20_000, 32, seed=1)
    codes = book.codewords(np.arange(20_000)).astype(float)
    half = book.column_lengths()
    assert np.abs(codes.mean(axis=0)[half < 1000]).max() < 0.05  # balanced over many periods
    assert np.all(half[0::2] == half[1::2]) and half.min() >= 2.0  # pairs share a period ≥ 4
    # Each pair is a quarter period apart: uncorrelated over whole periods.
    pair_corr = np.mean(codes[:, 0::2] * codes[:, 1::2], axis=0)
    assert np.abs(pair_corr[half[0::2] < 1000]).max() < 0.1
    # Neighbouring places share most of their codeword (what route decoding relies on).
    assert np.mean(codes[1:] == codes[:-1]) > 0.8


def test_random_codes_have_no_route_structure() -> None:
    codes = Codebook("random", 20_000, 32, seed=1).codewords(np.arange(20_000))
    assert np.abs(codes.mean(axis=0)).max() < 0.05
    assert 0.45 < np.mean(codes[1:] == codes[:-1]) < 0.55


@pytest.mark.parametrize("kwargs, match", [
    ({"family": "nope", "n_places": 10, "n_codes": 8}, "family"),
    ({"family": "periodic", "n_places": 1, "n_codes": 8}, "N ≥ 2"),
    ({"family": "periodic", "n_places": 100, "n_codes": 3}, r"K in \[7"),
    ({"family": "binary", "n_places": 100, "n_codes": 8}, "exactly b = 7"),
    ({"family": "offset", "n_places": 100, "n_codes": 10_000}, r"K in \[7, "),
    ({"family": "random", "n_places": 100, "n_codes": 8, "seed": -1}, "seed"),
])
def test_invalid_codebooks_are_refused_with_a_reason(kwargs, match) -> None:
    with pytest.raises(InvalidParameterError, match=match):
        Codebook(**kwargs)


def test_places_outside_the_route_are_refused() -> None:
    with pytest.raises(InvalidParameterError, match=r"\[0, 50\)"):
        Codebook("periodic", 50, 16).codewords(np.array([50]))


def _sums_of_codewords(book: Codebook, block: int) -> np.ndarray:
    codes = book.codewords(np.arange(book.n_places)).astype(np.int64)
    return np.add.reduceat(codes, np.arange(0, book.n_places, block), axis=0)


@settings(max_examples=60, deadline=None)
@given(family=st.sampled_from(FAMILIES), n_places=st.integers(2, 3000), k=st.integers(1, 40),
       block=st.one_of(st.just(1), st.integers(1, 12), st.integers(1, 4000)), seed=st.integers(0, 2**32 - 1))
def test_block_sums_are_the_sums_of_the_codewords_of_each_block(family, n_places, k, block, seed) -> None:
    k = min(max(k, min_columns(family, n_places)), max_columns(family, n_places))
    if family == "binary":
        k = min_columns(family, n_places)
    book = Codebook(family, n_places, k, seed)
    sums = book.block_sums(block)
    assert sums.dtype == np.int32 and sums.shape == (-(-n_places // block), k)
    np.testing.assert_array_equal(sums, _sums_of_codewords(book, block))


_EDGES = st.sampled_from([0, 1, 2**62, 2**63 - 1, 2**63, 2**63 + 1, 2**64 - 1])


@settings(max_examples=80, deadline=None)
@given(n_places=st.integers(8, 2000), block=st.integers(8, 700),
       frequency=st.one_of(_EDGES, st.integers(0, 2**64 - 1)), phase=st.one_of(_EDGES, st.integers(0, 2**64 - 1)))
def test_periodic_block_sums_are_exact_for_any_fixed_point_frequency_and_phase(n_places, block, frequency, phase) -> None:
    # The closed form's switch points s_i = −i·F and e_i = s_i + 2⁶³ hit 0 and wrap around 2⁶⁴ here
    # (F = 2⁶², 2⁶³, 2⁶⁴ − 1, …), cases the seeded frequencies reach only by chance.
    book = Codebook("periodic", n_places, 16, seed=0)
    book._params["frequency"][:8] = np.uint64(frequency)
    book._params["phase"][:8] = np.uint64(phase)
    book._params["frequency"][8:] = np.uint64(frequency) + np.arange(8, dtype=np.uint64)
    np.testing.assert_array_equal(book.block_sums(block), _sums_of_codewords(book, block))


def test_block_sums_refuse_an_empty_block() -> None:
    with pytest.raises(InvalidParameterError, match="block must be ≥ 1"):
        Codebook("periodic", 50, 16).block_sums(0)
