"""The random family's generation rules: the per-bit rule old model files need, the grouped rule new fits use.

The references here are written with Python integers (no numpy), from the formulas in
:mod:`btel.methods.codes.hashing`, so a change to the vectorised code cannot move both sides.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import btel
from btel.datasets import synthetic_route
from btel.exceptions import InvalidParameterError, ModelFileError
from btel.methods.codes.codebook import FAMILIES, Codebook, max_columns, min_columns
from btel.methods.codes.codewords import Codewords
from btel.methods.codes.estimator import CodeLocalizer
from btel.methods.codes.hashing import CURRENT_RULE, LEGACY_RULE
from btel.core.modelfile import load_arrays, save_arrays

MASK = (1 << 64) - 1
GAMMA = 0x9E3779B97F4A7C15
RANDOM_ID = FAMILIES.index("random") + 1


def _mix(z: int) -> int:
    z = ((z ^ (z >> 30)) * 0xBF58476D1CE4E5B9) & MASK
    z = ((z ^ (z >> 27)) * 0x94D049BB133111EB) & MASK
    return z ^ (z >> 31)


def _key(*keys: int) -> int:
    z = 0
    for key in keys:
        z = _mix(z ^ ((key + GAMMA) & MASK))
    return z


def _old_rule(n: int, k: int, seed: int) -> np.ndarray:
    """Rule 1: column c of place i is the top bit of splitmix64(i·γ ⊕ key_c), key_c = H(seed, random, c)."""
    keys = [_key(seed, RANDOM_ID, c) for c in range(k)]
    return np.array([[1 if _mix(((i * GAMMA) & MASK) ^ keys[c]) >> 63 else -1 for c in range(k)] for i in range(n)],
                    dtype=np.int8)


def _new_rule(n: int, k: int, seed: int) -> np.ndarray:
    """Rule 2: column j of place i is bit j mod 64 of splitmix64(key_g + (i + 1)·γ), g = j // 64, key_g = H(seed, random, 2, g)."""
    keys = [_key(seed, RANDOM_ID, 2, g) for g in range(-(-k // 64))]
    hashes = [[_mix((keys[g] + (i + 1) * GAMMA) & MASK) for g in range(len(keys))] for i in range(n)]
    return np.array([[1 if (hashes[i][j // 64] >> (j % 64)) & 1 else -1 for j in range(k)] for i in range(n)],
                    dtype=np.int8)


@pytest.mark.parametrize("n, k, seed", [(40, 9, 0), (37, 70, 7), (20, 130, 2**32 - 1)])
def test_the_old_rule_still_gives_the_codewords_of_the_per_bit_formula(n, k, seed) -> None:
    book = Codebook("random", n, k, seed, rule=1)
    np.testing.assert_array_equal(book.codewords(np.arange(n)), _old_rule(n, k, seed))


@pytest.mark.parametrize("n, k, seed", [(40, 9, 0), (37, 70, 7), (20, 130, 2**32 - 1), (5, 64, 3)])
def test_the_new_rule_gives_the_codewords_of_the_grouped_formula(n, k, seed) -> None:
    book = Codebook("random", n, k, seed)
    assert book.rule == CURRENT_RULE == 2
    expected = _new_rule(n, k, seed)
    np.testing.assert_array_equal(book.codewords(np.arange(n)), expected)
    np.testing.assert_array_equal(book.packed(np.arange(n)), np.packbits(expected > 0, axis=1, bitorder="little"))


def test_the_new_rules_packed_codes_are_the_hash_bytes_in_little_endian_order() -> None:
    n, k, seed = 6, 128, 11
    keys = [_key(seed, RANDOM_ID, 2, g) for g in range(2)]
    hashes = b"".join(_mix((keys[g] + (i + 1) * GAMMA) & MASK).to_bytes(8, "little") for i in range(n) for g in range(2))
    np.testing.assert_array_equal(Codebook("random", n, k, seed).packed(np.arange(n)),
                                  np.frombuffer(hashes, dtype=np.uint8).reshape(n, 16))


def test_the_two_rules_differ_and_other_families_ignore_the_rule() -> None:
    places = np.arange(200)
    assert np.mean(Codebook("random", 200, 40, 1, rule=1).codewords(places)
                   == Codebook("random", 200, 40, 1, rule=2).codewords(places)) < 0.6
    for family in ("periodic", "blocks", "offset"):
        old, new = Codebook(family, 200, 20, 1, rule=1), Codebook(family, 200, 20, 1)
        assert old == new and old.rule == CURRENT_RULE
        np.testing.assert_array_equal(old.codewords(places), new.codewords(places))


@settings(max_examples=60, deadline=None)
@given(family=st.sampled_from(FAMILIES), rule=st.sampled_from([1, 2]), n_places=st.integers(2, 700),
       k=st.integers(1, 300), seed=st.integers(0, 2**32 - 1), data=st.data())
def test_codeword_signs_are_the_unpacked_packed_codes_for_any_columns(family, rule, n_places, k, seed, data) -> None:
    k = min(max(k, min_columns(family, n_places)), max_columns(family, n_places))
    if family == "binary":
        k = min_columns(family, n_places)
    book = Codebook(family, n_places, k, seed, rule=rule)
    places = np.asarray(data.draw(st.lists(st.integers(0, n_places - 1), min_size=0, max_size=40)), dtype=np.int64)
    packed = book.packed(places)
    assert packed.dtype == np.uint8 and packed.shape == (places.size, -(-k // 8))
    if k % 8:  # the last byte's unused high bits are zero, as np.packbits leaves them
        assert not np.any(packed[:, -1] >> (k % 8))
    signs = np.unpackbits(packed, axis=1, count=k, bitorder="little").astype(np.int8) * 2 - 1
    np.testing.assert_array_equal(book.codewords(places), signs)
    columns = np.asarray(data.draw(st.lists(st.integers(0, k - 1), min_size=1, max_size=2 * k)))
    np.testing.assert_array_equal(book.codewords(places, columns), signs[:, columns])
    a = data.draw(st.integers(0, k - 1))
    b = data.draw(st.integers(a, k))
    np.testing.assert_array_equal(book.codewords(places, slice(a, b)), signs[:, a:b])
    out = np.full_like(packed, 0xFF)
    assert book.packed(places, out=out) is out
    np.testing.assert_array_equal(out, packed)


@pytest.mark.parametrize("rule", [1, 2])
def test_block_sums_signs_and_caches_follow_the_codewords_under_either_rule(rule) -> None:
    n, k, block = 1001, 70, 13
    book = Codebook("random", n, k, 5, rule=rule)
    codes = book.codewords(np.arange(n))
    starts = np.arange(0, n, block)
    np.testing.assert_array_equal(book.block_sums(block), np.add.reduceat(codes.astype(np.int32), starts, axis=0))
    low, high = np.minimum.reduceat(codes, starts, axis=0), np.maximum.reduceat(codes, starts, axis=0)
    np.testing.assert_array_equal(book.block_signs(block), np.where(low == high, low, 0))
    cache = Codewords(book)
    np.testing.assert_array_equal(cache.dense()[:, :k], codes)
    places = np.array([0, 999, 1000, 3, 3])
    np.testing.assert_array_equal(cache.packed_of(places), np.packbits(codes[places] > 0, axis=1, bitorder="little"))
    np.testing.assert_array_equal(cache.of(places)[:, :k], codes[places])


def test_invalid_rules_are_refused() -> None:
    for rule in (0, 3, -1, True, "2", 2.0, None):
        with pytest.raises(InvalidParameterError, match="code rule must be one of"):
            Codebook("random", 100, 16, 0, rule=rule)


# ----------------------------------------------------------------------------- model files
@pytest.fixture(scope="module")
def fitted(tmp_path_factory):
    r = synthetic_route(800, 24, condition_shift=0.5, seed=2)
    model = CodeLocalizer(code="random", n_codes=75, decode="exact").fit(r.map)
    path = model.save(tmp_path_factory.mktemp("rule") / "new.btel")
    return model, path, r.queries


def _rewrite_state(src, dst, edit) -> object:
    arrays, header = load_arrays(src)
    edit(header["state"])
    return save_arrays(dst, arrays, header)


def test_new_fits_record_the_current_rule_and_load_with_it(fitted) -> None:
    model, path, Q = fitted
    _, header = load_arrays(path)
    assert header["state"]["code_rule"] == CURRENT_RULE == model.codebook_.rule
    back = btel.load(path)
    assert back.codebook_ == model.codebook_
    np.testing.assert_array_equal(back.predict(Q), model.predict(Q))


def test_a_file_without_a_rule_loads_with_the_per_bit_rule_and_predicts_as_before(fitted, tmp_path) -> None:
    model, path, Q = fitted
    # The model as a file written before rules were recorded decoded it: the same weights, rule-1 codewords.
    before = btel.load(path)
    before._set_structure(Codebook("random", before.n_places_, before.n_codes_, before.code_seed_, rule=LEGACY_RULE))
    old_file = _rewrite_state(path, tmp_path / "old.btel", lambda state: state.pop("code_rule"))
    assert "code_rule" not in json.dumps(load_arrays(old_file)[1])
    old = btel.load(old_file)
    assert old.codebook_.rule == LEGACY_RULE and old.codebook_ == before.codebook_
    np.testing.assert_array_equal(old.codebook_.codewords(np.arange(40), np.arange(75)), _old_rule(40, 75, old.code_seed_))
    np.testing.assert_array_equal(old.predict(Q), before.predict(Q))
    for k in (1, 4):
        for got, expected in zip(old.search(Q, k), before.search(Q, k)):
            np.testing.assert_array_equal(got, expected)
    # Saved again, it keeps its rule (and so its codewords).
    again = btel.load(old.save(tmp_path / "again.btel"))
    assert again.codebook_.rule == LEGACY_RULE
    np.testing.assert_array_equal(again.predict(Q), before.predict(Q))


def test_every_exact_path_of_an_old_rule_model_gives_the_true_top_k(fitted, tmp_path) -> None:
    from test_code_decoding import PATHS, _check_exact, _reference

    model, path, Q = fitted
    old = btel.load(_rewrite_state(path, tmp_path / "old.btel", lambda state: state.pop("code_rule")))
    M = old._padded(old._margins(old._check_queries(Q[:5])))
    reference = _reference(old, M)
    for p in PATHS:
        _check_exact(*old._exact_search(M, 3, p), reference)


@pytest.mark.parametrize("value", [0, 3, 99, -1, "2", 2.0, True, None, [2]])
def test_bad_rules_in_a_file_are_a_model_file_error(fitted, tmp_path, value) -> None:
    _, path, _ = fitted
    bad = _rewrite_state(path, tmp_path / "bad.btel", lambda state: state.__setitem__("code_rule", value))
    with pytest.raises(ModelFileError, match="code_rule"):
        btel.load(bad)
