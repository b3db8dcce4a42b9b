"""btel.methods.codes.decoding: every exact decode path gives the answer of scoring every place in float64."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from btel.methods.codes.decoding import BlockDecoder, block_size, choose_path
from btel.methods.codes.codebook import FAMILIES, Codebook
from btel.methods.codes.estimator import CodeLocalizer
from btel.datasets import synthetic_route

PATHS = ("bounded", "dense", "scan", "probe")


def _reference(model: CodeLocalizer, M: np.ndarray) -> np.ndarray:
    codes = model.codebook_.codewords(np.arange(model.n_places_)).astype(np.float64)
    return M[:, : model.n_codes_].astype(np.float64) @ codes.T


def _check_exact(scores: np.ndarray, places: np.ndarray, reference: np.ndarray) -> None:
    """Scores are the true top-k scores (float32 rounding); places match wherever no near-tie makes them ambiguous."""
    k = scores.shape[1]
    ordered = -np.sort(-reference, axis=1)[:, :k]
    scale = np.abs(reference).max()
    tol = 1e-4 * scale + 1e-6
    np.testing.assert_allclose(scores, ordered, rtol=0, atol=tol)
    np.testing.assert_allclose(np.take_along_axis(reference, places, axis=1), ordered, rtol=0, atol=tol)
    assert all(len(set(row)) == k for row in places.tolist())


@pytest.fixture(scope="module")
def route() -> tuple[np.ndarray, np.ndarray]:
    r = synthetic_route(1500, 48, condition_shift=0.5, seed=3)
    return r.map, r.queries


_MODELS: dict[str, CodeLocalizer] = {}


def _model(family: str, X: np.ndarray) -> CodeLocalizer:
    if family not in _MODELS:
        n_codes = None if family == "binary" else 60  # 60: a padded last byte
        _MODELS[family] = CodeLocalizer(code=family, n_codes=n_codes, decode="exact").fit(X)
    return _MODELS[family]


@settings(max_examples=25, deadline=None)
@given(family=st.sampled_from(FAMILIES), seed=st.integers(0, 10_000), k=st.sampled_from([1, 3, 10]),
       noise=st.floats(0.0, 3.0))
def test_every_exact_path_gives_the_true_top_k(route, family, seed, k, noise) -> None:
    X, Q = route
    model = _model(family, X)
    rng = np.random.default_rng(seed)
    # Margins of real queries, with extra noise (noise = 3: mostly wrong margins, loose bounds).
    M = model._margins(model._check_queries(Q[rng.choice(len(Q), 4)]))
    M = model._padded(M + noise * rng.normal(size=M.shape).astype(np.float32) * np.abs(M).mean())
    reference = _reference(model, M)
    for path in PATHS:
        scores, places = model._exact_search(M, k, path)
        _check_exact(scores, places, reference)


def test_search_single_queries_and_batches_agree_and_report_the_path(route) -> None:
    X, Q = route
    model = CodeLocalizer(n_codes=400, decode="exact").fit(X)  # N·W = 1500 × 400: past the small-map rule
    assert model.exact_path(1) == "bounded" and model.exact_path(64) == "probe"
    batch = model.search(Q[:40], 5)
    M = model._padded(model._margins(model._check_queries(Q[:40])))
    reference = _reference(model, M)
    _check_exact(*batch, reference)
    for j in range(0, 40, 7):
        single = model.search(Q[j : j + 1], 5)
        _check_exact(*single, reference[j : j + 1])
        # Same places unless two scores tie within float32 rounding (summed in another order).
        assert np.mean(single[1][0] == batch[1][j]) >= 0.6


def test_the_bounds_hold_and_the_visited_blocks_shrink_with_good_margins(route) -> None:
    X, Q = route
    model = _model("periodic", X)
    decoder = model._codewords.decoder()
    M = model._padded(model._margins(model._check_queries(Q[:50])))
    U = decoder.bounds(M)
    S = _reference(model, M)
    per_block = np.maximum.reduceat(S, np.arange(0, S.shape[1], decoder.block), axis=1)
    assert np.all(per_block <= U + 1e-3)
    _, _, visited = decoder.search(M, 1)
    assert np.median(visited) < U.shape[1]  # real queries do not need every block


def test_a_packed_cache_past_its_limit_generates_codewords(route, monkeypatch) -> None:
    import btel.methods.codes.codewords as codewords

    X, Q = route
    model = CodeLocalizer(n_codes=60, decode="exact").fit(X)
    M = model._padded(model._margins(model._check_queries(Q[:5])))
    expected = model._exact_search(M, 3, "bounded")
    fresh = CodeLocalizer(n_codes=60, decode="exact").fit(X)
    monkeypatch.setattr(codewords, "PACKED_CACHE_BYTES", 10)
    got = fresh._exact_search(M, 3, "bounded")
    np.testing.assert_array_equal(got[1], expected[1])
    assert fresh._codewords.packed is None


def test_the_bounded_search_scores_the_same_from_float32_and_from_packed_codewords(route) -> None:
    X, Q = route
    model = CodeLocalizer(n_codes=60, decode="exact").fit(X)
    M = model._padded(model._margins(model._check_queries(Q[:30])))
    codewords = model._codewords
    from_dense = codewords.decoder()
    from_packed = BlockDecoder(model.codebook_, codewords.width, codewords.packed_of)
    assert from_dense.dense is not None and from_packed.dense is None
    reference = _reference(model, M)
    for k in (1, 4):
        dense_s, dense_p, dense_v = from_dense.search(M, k)
        packed_s, packed_p, packed_v = from_packed.search(M, k)
        _check_exact(dense_s, dense_p, reference)
        _check_exact(packed_s, packed_p, reference)
        np.testing.assert_allclose(dense_s, packed_s, rtol=0, atol=1e-4 * np.abs(reference).max())
        assert np.mean(dense_p == packed_p) >= 0.9  # the same places but for ties within float32 rounding
        np.testing.assert_array_equal(dense_v, packed_v)  # the same bounds: the same blocks visited


@pytest.mark.parametrize("path", ["bounded", "dense"])
def test_margins_that_overflow_in_the_sums_are_an_error_on_every_path(route, path) -> None:
    from btel.exceptions import InvalidAnswerError

    X, Q = route
    model = CodeLocalizer(n_codes=400, decode="exact").fit(X)
    M = np.full((1, model._codewords.width), 1e37, dtype=np.float32)  # finite, but 400 of them overflow
    M[0, ::3] = -1e37
    with pytest.raises(InvalidAnswerError, match="non-finite"):
        model._exact_search(M, 1, path)


def test_the_first_query_fills_only_the_blocks_it_scores(route, monkeypatch) -> None:
    import btel.methods.codes.codewords as codewords

    X, Q = route
    monkeypatch.setattr(codewords, "DENSE_CACHE_BYTES", 10)  # no float32 codewords: packed ones, filled on demand
    model = CodeLocalizer(n_codes=400, decode="exact").fit(X)  # past the small-map rule: bounded
    assert model.exact_path(1) == "bounded"
    model.predict(Q[:1])
    filled = model._codewords.filled
    assert filled is not None and 0 < filled.sum() < filled.size


@pytest.mark.parametrize("family", FAMILIES)
@pytest.mark.parametrize("n, block", [(1000, 7), (777, 1), (5000, 64), (300, 300), (300, 1000), (70_000, 2)])
def test_block_signs_are_the_constant_columns_of_each_block(family, n, block) -> None:
    k = int(np.ceil(np.log2(n))) if family == "binary" else 30
    book = Codebook(family, n, k, seed=n % 7)
    signs = book.block_signs(block)
    codes = book.codewords(np.arange(n))
    low = np.minimum.reduceat(codes, np.arange(0, n, block), axis=0)
    high = np.maximum.reduceat(codes, np.arange(0, n, block), axis=0)
    np.testing.assert_array_equal(signs, np.where(low == high, low, 0))


def test_rules() -> None:
    assert block_size(100) == 10 and block_size(10**8) == 1024 and block_size(10) == 8
    assert choose_path(10**4, 472, 1, True, True) == "bounded"
    assert choose_path(10**4, 472, 64, True, True) == "probe"
    assert choose_path(10**4, 472, 64, True, True, visited=0.1) == "bounded"
    assert choose_path(10**4, 472, 64, True, True, visited=0.9) == "dense"
    assert choose_path(500, 472, 1, True, True) == "dense"
    assert choose_path(10**6, 472, 64, True, False) == "bounded"
    assert choose_path(10**6, 472, 1, False, False) == "scan"
    assert choose_path(1000, 472, 1, False, True) == "dense"
    book = Codebook("periodic", 500, 16, 0)
    decoder = BlockDecoder(book, 16, lambda p: np.packbits(book.codewords(p) > 0, axis=1, bitorder="little"))
    assert decoder.constant.shape == (-(-500 // decoder.block), 16)


def _reference_from_queries(model: CodeLocalizer, Q: np.ndarray) -> np.ndarray:
    """m · c_i in float64 from the queries: margins (q'·W + b) in float64, then every codeword."""
    Z = np.asarray(model._check_queries(Q), dtype=np.float64)
    if model.columns_ is not None:
        Z = Z[:, model.columns_.astype(np.intp)]
    margins = Z @ model.weights_.dequantise().T.astype(np.float64) + model.bias_.astype(np.float64)
    codes = model.codebook_.codewords(np.arange(model.n_places_)).astype(np.float64)
    return margins @ codes.T


@pytest.mark.parametrize("family", ["periodic", "random"])
@pytest.mark.parametrize("normalize", ["l2", "none"])
def test_the_composed_map_gives_the_true_top_k_on_maps_with_few_places_per_code(family, normalize) -> None:
    # N = 150 places, K = 200 codes: scoring every place by V = W·Cᵀ (d' × N) is the cheaper product.
    r = synthetic_route(150, 40, condition_shift=0.5, seed=5)
    model = CodeLocalizer(code=family, n_codes=200, n_features=30, decode="exact", normalize=normalize).fit(r.map)
    assert model.exact_path(1) == "composed" and model.exact_path(64) == "composed"
    reference = _reference_from_queries(model, r.queries)
    for k in (1, 5):
        _check_exact(*model.search(r.queries, k), reference)
        for j in range(0, 150, 37):
            _check_exact(*model.search(r.queries[j : j + 1], k), reference[j : j + 1])
    single = np.concatenate([model.predict(r.queries[j : j + 1]) for j in range(150)])
    np.testing.assert_array_equal(single, model.predict(r.queries))
    np.testing.assert_array_equal(model.predict(r.queries), model.search(r.queries, 1)[1][:, 0])
    np.testing.assert_allclose(model.place_scores(r.queries), reference, rtol=0, atol=1e-4 * np.abs(reference).max())


@pytest.mark.parametrize("normalize", ["l2", "none"])
def test_the_bounded_search_from_composed_rows_gives_the_true_top_k(normalize) -> None:
    from btel.methods.codes.decoding import ComposedRows

    # d' = 40 columns against K = 400 codes on 1,500 places: a scored place costs d' multiply-adds
    # through the composed rows instead of 400 through the codewords.
    r = synthetic_route(1500, 48, condition_shift=0.5, seed=9)
    model = CodeLocalizer(n_codes=400, n_features=40, decode="exact", normalize=normalize).fit(r.map)
    assert model.exact_path(1) == "bounded" and model.exact_path(64) == "probe"
    reference = _reference_from_queries(model, r.queries)
    for k in (1, 5):
        _check_exact(*model.search(r.queries, k), reference)          # a batch: probe, then its path
        for j in range(0, 1500, 97):
            _check_exact(*model.search(r.queries[j : j + 1], k), reference[j : j + 1])
    rows = model._cache.composed_rows
    assert isinstance(rows, ComposedRows) and rows.rows.shape == (1500, 40)
    # The same answers as the bounded search over the codewords, visiting the same blocks.
    Z = model._check_queries(r.queries[:200])
    M = model._padded_margins(Z)
    s_rows, p_rows, v_rows = model._codewords.decoder().search(M, 3, rows, model._kept(Z))
    s_codes, p_codes, v_codes = model._codewords.decoder().search(M, 3)
    np.testing.assert_allclose(s_rows, s_codes, rtol=0, atol=1e-4 * np.abs(reference).max())
    assert np.mean(p_rows == p_codes) >= 0.99 and abs(v_rows.mean() - v_codes.mean()) <= 0.5
    single = np.concatenate([model.predict(r.queries[j : j + 1]) for j in range(0, 1500, 7)])
    np.testing.assert_array_equal(single, model.predict(r.queries[::7]))


def test_the_composed_map_refuses_scores_that_overflow() -> None:
    from btel.exceptions import InvalidAnswerError

    r = synthetic_route(150, 40, seed=5)
    model = CodeLocalizer(n_codes=200, decode="exact", normalize="none").fit(r.map)
    assert model.exact_path(1) == "composed"
    Q = np.full((2, 40), 3e38, dtype=np.float32)  # finite queries whose scores overflow float32
    with pytest.raises(InvalidAnswerError, match="non-finite"):
        model.predict(Q[:1])
    with pytest.raises(InvalidAnswerError, match="non-finite"):
        model.predict(Q)
    with pytest.raises(InvalidAnswerError, match="non-finite"):
        model.search(Q, 3)


def test_decode_coarse_is_kept_where_the_composed_map_would_serve() -> None:
    r = synthetic_route(150, 40, seed=5)
    model = CodeLocalizer(n_codes=200, decode="coarse", coarse_block=10, coarse_candidates=2).fit(r.map)
    assert model._coarse_plan(1) == (10, 2)
    calls = []
    codewords = model._codewords
    original = codewords.coarse_search
    codewords.coarse_search = lambda *a, **kw: calls.append(1) or original(*a, **kw)
    model.predict(r.queries[:3])
    model.search(r.queries[:1], 4)
    assert len(calls) == 2

def test_the_scan_index_holds_every_codeword_once_when_filled_block_by_block(route, monkeypatch) -> None:
    import faiss

    import btel.methods.codes.codewords as codewords
    import btel.methods.codes.hashing as hashing

    X, Q = route
    model = _model("random", X)
    # 97 places per block (K = 60: 8 bytes each): 16 blocks, a short last one; hashed 13 places at a time.
    monkeypatch.setattr(codewords, "BLOCK_VALUES", 97 * 8 * 8)
    monkeypatch.setattr(hashing, "_GROUP_PLACES", 13)
    scan = codewords.Codewords(model.codebook_).adc_index()
    index = scan.index
    packed = np.packbits(model.codebook_.codewords(np.arange(1500)) > 0, axis=1, bitorder="little")
    assert index.ntotal == 1500 and index.codes.size() == packed.size
    np.testing.assert_array_equal(faiss.vector_to_array(index.codes).reshape(packed.shape), packed)
    M = model._padded(model._margins(model._check_queries(Q[:6])))
    scores, places = scan.search(M, 4)
    _check_exact(scores.astype(np.float64), places.astype(np.int64), _reference(model, M))


def test_the_scan_answers_a_batch_in_chunks_as_in_one_call(route, monkeypatch) -> None:
    import btel.methods.codes.codewords as codewords

    X, Q = route
    model = _model("random", X)
    scan = codewords.Codewords(model.codebook_).adc_index()
    M = model._padded(model._margins(model._check_queries(Q[:23])))
    whole = scan.index.search(M, 5)
    monkeypatch.setattr(codewords, "SCAN_TABLE_VALUES", 4 * 8 * 256)  # 4 queries per call: 6 calls, a short last one
    chunked = scan.search(M, 5)
    for got, expected in zip(chunked, whole):
        np.testing.assert_array_equal(got, expected)


def test_packed_look_ups_in_small_pieces_score_the_same(route, monkeypatch) -> None:
    import btel.methods.codes.decoding as decoding

    X, Q = route
    model = CodeLocalizer(n_codes=60, decode="exact").fit(X)
    M = model._padded(model._margins(model._check_queries(Q[:10])))
    codewords = model._codewords
    whole = BlockDecoder(model.codebook_, codewords.width, codewords.packed_of).search(M, 3)
    monkeypatch.setattr(decoding, "LOOKUP_VALUES", 8 * 37)  # 37 places per piece: pieces split blocks
    pieces = BlockDecoder(model.codebook_, codewords.width, codewords.packed_of).search(M, 3)
    for a, b in zip(whole, pieces):
        np.testing.assert_array_equal(a, b)
    _check_exact(pieces[0], pieces[1], _reference(model, M))


def test_packed_look_ups_past_2048_columns_index_every_group(route) -> None:
    # ⌈K/8⌉ = 263 groups: the look-up index g·256 + b no longer fits uint16.
    X, Q = route
    model = CodeLocalizer(n_codes=2100, decode="exact").fit(X)
    M = model._padded(model._margins(model._check_queries(Q[:6])))
    codewords = model._codewords
    from_packed = BlockDecoder(model.codebook_, codewords.width, codewords.packed_of)
    _check_exact(*from_packed.search(M, 3)[:2], _reference(model, M))


_ONE_QUERY: dict[str, CodeLocalizer] = {}


def _one_query_model(kind: str) -> CodeLocalizer:
    """A model whose single queries take the one-query bounded search: from the float32 codewords ('codes': K = 40
    codes, d' = 48, on a map the small-map rule is lowered for) or from the composed rows (d' = 40 < K = 400)."""
    import btel.methods.codes.decoding as decoding

    if kind not in _ONE_QUERY:
        r = synthetic_route(1500, 48, condition_shift=0.5, seed=9)
        with pytest.MonkeyPatch.context() as patch:
            if kind == "codes":  # 1500 × 40 codeword values: 'dense' by the small-map rule, 'bounded' past it
                patch.setattr(decoding, "DENSE_SMALL_VALUES", 1000)
            model = CodeLocalizer(n_codes=40 if kind == "codes" else 400, n_features=None if kind == "codes" else 40,
                                  decode="exact").fit(r.map)
            model._one_query_decoder()  # decided under the lowered rule, kept for the model
        _ONE_QUERY[kind] = model
    return _ONE_QUERY[kind]


@settings(max_examples=30, deadline=None)
@given(kind=st.sampled_from(["codes", "rows"]), seed=st.integers(0, 10_000), noise=st.floats(0.0, 3.0),
       scale=st.sampled_from([1e-3, 1.0, 1e4]))
def test_the_one_query_search_gives_the_true_best_place(kind, seed, noise, scale) -> None:
    route_ = synthetic_route(1500, 48, condition_shift=0.5, seed=9)
    model = _one_query_model(kind)
    decoder = model._one_query_decoder()
    assert decoder is not None and (model._composed_rows() is not None) == (kind == "rows")
    rng = np.random.default_rng(seed)
    # A real query, moved by noise (noise = 3: mostly wrong margins, loose bounds) and scaled.
    q = route_.queries[rng.integers(len(route_.queries))][None]
    q = (scale * (q + noise * rng.normal(size=q.shape) * np.abs(q).mean())).astype(np.float32)
    scores, places = model.search(q, 1)
    reference = _reference_from_queries(model, q)
    _check_exact(scores, places, reference)
    assert model.predict(q)[0] == places[0, 0]
    # The batch decoder's answer for the same margins: the same place but for a tie within float32 rounding.
    Z = model._check_queries(q)
    rows = model._composed_rows()
    s_batch, p_batch, _ = decoder.search(model._padded_margins(Z), 1, rows, None if rows is None else model._kept(Z))
    assert p_batch[0, 0] == places[0, 0] or abs(reference[0, p_batch[0, 0]] - reference[0, places[0, 0]]) <= \
        1e-4 * np.abs(reference).max()


def test_the_one_query_search_breaks_ties_to_the_lower_place_across_rounds() -> None:
    model = _one_query_model("codes")
    decoder = model._one_query_decoder()
    m = np.zeros(model._codewords.width, dtype=np.float32)  # every place scores 0: the answer is place 0
    assert decoder.search_one(m) == (0.0, 0)


def test_the_one_query_search_is_kept_per_decode_setting_and_refuses_overflow() -> None:
    from btel.exceptions import InvalidAnswerError

    model = _one_query_model("rows")
    assert model._one_query_decoder() is not None
    model.set_params(decode="coarse")
    try:
        assert model._one_query_decoder() is None  # coarse to fine decodes single queries then
    finally:
        model.set_params(decode="exact")
    assert model._one_query_decoder() is not None
    m = np.full(model._codewords.width, 3e38, dtype=np.float32)  # finite margins whose sums overflow
    assert not np.isfinite(model._one_query_decoder().search_one(m)[0])
    model = _one_query_model("codes")  # scores read from the codewords: the margins themselves scaled up
    weights, bias = model._weights_dense()
    model._cache.weights = (weights * np.float32(1e38), bias)
    try:
        with pytest.raises(InvalidAnswerError, match="non-finite"):
            model.predict(np.ones((1, 48), dtype=np.float32))
        with pytest.raises(InvalidAnswerError, match="non-finite"):
            model.search(np.ones((1, 48), dtype=np.float32), 1)
    finally:
        model._cache.weights = (weights, bias)


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 10_000), k=st.sampled_from([1, 4]), block=st.sampled_from([7, 16, 40]),
       candidates=st.sampled_from([1, 3, 8]), noise=st.floats(0.0, 2.0))
def test_the_coarse_refine_scores_its_candidates_exactly_with_and_without_the_packed_cache(
        route, seed, k, block, candidates, noise) -> None:
    import btel.methods.codes.codewords as codewords

    X, Q = route
    model = _model("periodic", X)
    rng = np.random.default_rng(seed)
    M = model._margins(model._check_queries(Q[rng.choice(len(Q), 3)]))
    M = model._padded(M + noise * rng.normal(size=M.shape).astype(np.float32) * np.abs(M).mean())
    cw = model._codewords
    scores, places = cw.coarse_search(M, k, block, candidates)
    reference = _reference(model, M)
    coarse = M @ cw.block_means(block).T
    n_blocks = coarse.shape[1]
    for q in range(M.shape[0]):
        blocks = np.argpartition(coarse[q], n_blocks - candidates)[n_blocks - candidates :]
        pool = np.concatenate([np.arange(j * block, min(1500, (j + 1) * block)) for j in blocks])
        assert set(places[q].tolist()) <= set(pool.tolist()) and len(set(places[q].tolist())) == k
        _check_exact(scores[q : q + 1], np.searchsorted(np.sort(pool), places[q : q + 1]),
                     reference[q : q + 1, np.sort(pool)])
    fresh = codewords.Codewords(model.codebook_)
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(codewords, "PACKED_CACHE_BYTES", 10)  # numpy look-ups of generated codewords
        lookups = fresh.coarse_search(M, k, block, candidates)
    assert fresh.candidates is None and cw.candidates is not None
    np.testing.assert_allclose(lookups[0], scores, rtol=0, atol=1e-4 * np.abs(reference).max())


def test_block_runs_merge_adjacent_blocks_and_end_the_last_at_the_map() -> None:
    from btel.methods.codes.codewords import block_runs

    assert block_runs(np.array([0, 1, 3, 5, 6]), 10, 62) == [(0, 20), (30, 40), (50, 62)]
    assert block_runs(np.array([2]), 10, 25) == [(20, 25)]
    assert block_runs(np.array([0, 2, 4]), 10, 100) == [(0, 10), (20, 30), (40, 50)]
