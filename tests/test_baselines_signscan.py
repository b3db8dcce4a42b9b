"""Asymmetric scores of packed sign codes (btel.methods.baselines.signscan): both scans, exact, in place."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from btel.methods.baselines import signscan


def _codes_and_queries(n_rows: int, n_bits: int, n_queries: int, seed: int = 0):
    """Packed codes, queries, and every score from the unpacked ±1 codes (float64, on the queries' grid)."""
    rng = np.random.default_rng(seed)
    bits = rng.integers(0, 2, size=(n_rows, n_bits), dtype=np.uint8)
    codes = np.packbits(bits, axis=1)
    P = rng.standard_normal((n_queries, n_bits)).astype(np.float32)
    grid = signscan.query_rows(P, codes.shape[1])[:, :n_bits].astype(np.float64)
    return codes, P, grid @ (bits.astype(np.float64) * 2 - 1).T


@pytest.mark.parametrize("n_bits", [8, 13, 203])
@pytest.mark.parametrize("k", [1, 6, 300])
@pytest.mark.parametrize("block_values", [signscan.BLOCK_VALUES, 1 << 9])
def test_both_scans_give_the_true_top_k_and_every_score(n_bits, k, block_values, monkeypatch) -> None:
    """Small blocks force many blocks of rows and chunks of queries, merged block by block."""
    monkeypatch.setattr(signscan, "BLOCK_VALUES", block_values)
    codes, P, reference = _codes_and_queries(300, n_bits, 12)
    tables = signscan.byte_tables(codes.shape[1])
    padded = signscan.query_rows(P, codes.shape[1])
    assert padded.shape == (12, 8 * codes.shape[1]) and not padded[:, n_bits:].any()
    for scores, rows in (signscan.scan_tables(tables, codes, padded, k),
                         signscan.scan_blocks(codes, padded, k)):
        assert scores.shape == rows.shape == (12, k) and scores.dtype == np.float64 and rows.dtype == np.int64
        np.testing.assert_allclose(scores, np.take_along_axis(reference, rows, axis=1), atol=1e-4)
        np.testing.assert_allclose(scores[:, -1], np.sort(reference, axis=1)[:, -k], atol=1e-4)
        assert (np.diff(scores, axis=1) <= 1e-6).all()
        assert all(len(set(r)) == k for r in rows.tolist())
    np.testing.assert_allclose(signscan.scores(codes, P), reference, atol=1e-4)
    # On the grid every sum is exact: both scans give the very same scores, whatever the batch.
    tables_values, tables_rows = signscan.scan_tables(tables, codes, padded, k)
    blocks_values, blocks_rows = signscan.scan_blocks(codes, padded, k)
    np.testing.assert_array_equal(tables_values, blocks_values)
    np.testing.assert_array_equal(signscan.scores(codes, P), reference)
    np.testing.assert_array_equal(signscan.scan_blocks(codes, padded[3:4], k)[0], blocks_values[3:4])


@settings(max_examples=40, deadline=None)
@given(width_bytes=st.integers(1, 1024), scale=st.floats(1e-6, 1e6), seed=st.integers(0, 2**31 - 1))
def test_query_rows_round_to_a_grid_where_every_sum_is_exact(width_bytes: int, scale: float, seed: int) -> None:
    P = (np.random.default_rng(seed).standard_normal((3, 8 * width_bytes)) * scale).astype(np.float32)
    G = signscan.query_rows(P, width_bytes).astype(np.float64)
    bound = np.abs(P).max(axis=1, keepdims=True) * P.shape[1]
    step = np.exp2(np.ceil(np.log2(bound)) - 24)
    assert np.all(np.abs(G - P) <= step / 2 + 1e-30)                        # rounded, not more
    assert np.all(G / step == np.rint(G / step))                             # on the grid
    assert np.all(np.abs(G).sum(axis=1) <= 2**24 * step[:, 0])               # every partial sum exact
    np.testing.assert_array_equal(signscan.query_rows(np.zeros((1, 8)), 1), np.zeros((1, 8)))


@pytest.mark.parametrize("n_queries", [1, signscan.TABLE_QUERIES - 1, signscan.TABLE_QUERIES, 50])
def test_search_takes_the_tables_for_a_few_queries_and_the_blocks_for_more(n_queries, monkeypatch) -> None:
    codes, P, reference = _codes_and_queries(200, 64, n_queries, seed=1)
    calls = []
    for name in ("scan_tables", "scan_blocks"):
        real = getattr(signscan, name)
        monkeypatch.setattr(signscan, name, lambda *a, real=real, name=name: calls.append(name) or real(*a))
    scores, rows = signscan.search(signscan.byte_tables(8), codes, P, 3)
    assert calls == ["scan_tables" if n_queries < signscan.TABLE_QUERIES else "scan_blocks"]
    np.testing.assert_allclose(scores, np.take_along_axis(reference, rows, axis=1), atol=1e-4)


def test_the_table_scan_lists_tied_rows_lower_row_first() -> None:
    codes, P, _ = _codes_and_queries(300, 32, 1, seed=2)
    codes[200:205] = codes[7]  # five copies of row 7: the same code, exactly tied scores
    P = np.unpackbits(codes[7:8], axis=1).astype(np.float32) * 2 - 1   # the query that row 7 answers best
    scores, rows = signscan.scan_tables(signscan.byte_tables(4), codes, signscan.query_rows(P, 4), 6)
    assert rows[0].tolist() == [7, 200, 201, 202, 203, 204] and len(set(scores[0].tolist())) == 1
    assert signscan.scan_tables(signscan.byte_tables(4), codes, signscan.query_rows(P, 4), 1)[1][0, 0] == 7


def test_the_byte_table_is_packbits_order() -> None:
    """Byte value v's ±1 pattern is its bits, most significant first, as np.packbits writes them."""
    bits = np.array([[1, 0, 0, 0, 0, 0, 1, 1]], dtype=np.uint8)
    v = int(np.packbits(bits, axis=1)[0, 0])
    np.testing.assert_array_equal(signscan.BYTE_SIGNS[v], bits[0] * 2.0 - 1)
