"""LSH: seeded sign random projections filling the budget, the projection regenerated from its seed."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import btel
from btel.methods.baselines.lsh import LSHLocalizer, projection_matrix
from btel.exceptions import BudgetTooSmallError, InvalidParameterError
from btel.methods import make_method


@pytest.fixture(scope="module")
def pair():
    from btel.datasets import synthetic_route

    r = synthetic_route(400, 64, condition_shift=0.5, seed=5)
    return r.map, r.queries


@pytest.mark.parametrize("cone", [False, True])
@pytest.mark.parametrize("budget", [1_000, 5_000, 40_000])
def test_bits_fill_the_budget_and_only_codes_and_mean_are_stored(pair, budget, cone) -> None:
    from btel.methods.baselines.lsh import CENTER_CONE, cone_ratio

    X, _ = pair
    if cone:  # every row plus one shared direction: the unit rows then lie in a narrow cone
        X = X + 3 * np.abs(X).max() * np.ones(X.shape[1], dtype=np.float32)
    assert (cone_ratio(btel.core.frontend.normalize_rows(X)) >= CENTER_CONE) == cone
    assert make_method("lsh", budget=budget).fit(X).mean_ is None   # the default: plain cosine, never centred
    model = make_method("lsh", budget=budget, center="auto").fit(X)
    # center='auto': the float16 mean only for a cone, and only when it costs ≤ 1/8 of the budget.
    centred = cone and 2 * 64 <= budget / 8
    assert (model.mean_ is not None) == centred
    assert model.n_bits_ == 8 * (budget - 2 * 64 * centred) // 400 and model.nbytes <= budget
    assert model.nbytes > budget - 400 / 8  # less than one more bit per row is left over
    # The projection costs 0 bytes.
    assert set(model.storage_breakdown()) == ({"codes", "mean"} if centred else {"codes"})


def test_cone_ratio_is_the_mean_rows_length_over_their_rms_length() -> None:
    from btel.methods.baselines.lsh import cone_ratio

    x = np.random.default_rng(0).normal(size=(1, 16)).astype(np.float32)
    assert cone_ratio(np.repeat(x, 5, axis=0)) == pytest.approx(1.0)
    assert cone_ratio(np.concatenate([x, -x])) == pytest.approx(0.0, abs=1e-7)
    assert cone_ratio(np.zeros((3, 4), dtype=np.float32)) == 0.0


@settings(max_examples=30, deadline=None)
@given(a=st.floats(0.0, 1.0), b=st.floats(0.0, 1.0))
def test_sign_bit_entropy_falls_from_one_bit_to_none_as_the_cone_narrows(a: float, b: float) -> None:
    from btel.methods.baselines.lsh import sign_bit_entropy

    lo, hi = sorted((a, b))
    assert 0.0 <= sign_bit_entropy(hi) <= sign_bit_entropy(lo) + 1e-9 <= 1.0 + 1e-9
    assert sign_bit_entropy(0.0) == pytest.approx(1.0) and sign_bit_entropy(1.0) == 0.0


def test_sign_bit_entropy_matches_the_entropy_of_simulated_uncentred_bits() -> None:
    """Unit rows in a cone of ratio c, random hyperplanes through the origin: the bits' mean entropy."""
    from btel.methods.baselines.lsh import cone_ratio, sign_bit_entropy

    rng = np.random.default_rng(0)
    d, n = 400, 4000
    for offset in (0.0, 0.05, 0.15):   # a shared direction of length 0, 1 and 3 × the rows' own: cone 0, 0.7, 0.95
        X = rng.normal(size=(n, d)) / np.sqrt(d) + offset
        X /= np.linalg.norm(X, axis=1, keepdims=True)
        p = ((X @ rng.normal(size=(d, 2000))) > 0).mean(axis=0)
        p = np.clip(p, 1e-12, 1 - 1e-12)
        measured = float(np.mean(-(p * np.log2(p) + (1 - p) * np.log2(1 - p))))
        assert sign_bit_entropy(cone_ratio(X)) == pytest.approx(measured, abs=0.03)


def test_effective_bits_count_centred_bits_whole_and_uncentred_bits_at_their_entropy() -> None:
    from btel.methods.baselines.lsh import sign_bit_entropy

    lsh = LSHLocalizer(center="auto")
    # Nordland's shape (N = 3576, d = 3780, cone ratio 0.75): 16 KB cannot afford the 7.6 KB mean, 64 KB can.
    assert lsh.effective_bits(3576, 3780, 16_000, 0.75) == pytest.approx(35 * sign_bit_entropy(0.75))
    assert lsh.effective_bits(3576, 3780, 64_000, 0.75) == 8 * (64_000 - 2 * 3780) // 3576
    assert lsh.effective_bits(200, 500, 4_000, 0.2) == pytest.approx(160 * sign_bit_entropy(0.2))
    assert lsh.effective_bits(3576, 3780, 500, 0.75) == 0.0   # no code fits
    # The default front end is the plain one: uncentred bits at their entropy at any budget.
    plain = LSHLocalizer().effective_bits(3576, 3780, 64_000, 0.75)
    assert plain == pytest.approx(143 * sign_bit_entropy(0.75))


def test_projection_is_regenerated_from_the_recorded_seed(pair, tmp_path) -> None:
    X, Q = pair
    model = LSHLocalizer(budget=8_000, random_state=None).fit(X)
    again = btel.load(model.save(tmp_path / "m.npz"))
    assert again.seed_ == model.seed_
    R = projection_matrix(64, model.n_bits_, model.seed_, "hadamard")
    np.testing.assert_array_equal(again.projection_.matrix(), R)
    np.testing.assert_array_equal(again.search(Q, 5)[1], model.search(Q, 5)[1])


def test_asymmetric_score_is_projected_query_times_the_sign_codes(pair) -> None:
    X, Q = pair
    model = LSHLocalizer(n_bits=64, center=False).fit(X)
    Z, Qz = btel.core.frontend.normalize_rows(X), btel.core.frontend.normalize_rows(Q[:5])
    R = projection_matrix(64, 64, 0, "hadamard")
    expected = (Qz @ R) @ np.sign(Z @ R).T
    np.testing.assert_allclose(model.place_scores(Q[:5]), expected, rtol=1e-4, atol=1e-3)


@pytest.mark.parametrize("d, bits", [(64, 64), (64, 200), (16, 40)])
def test_orthogonal_projection_is_orthonormal_blocks_of_the_seeds_gaussian(d, bits) -> None:
    R = projection_matrix(d, bits, 3, "orthogonal")
    G = projection_matrix(d, bits, 3, "gaussian")
    assert R.shape == G.shape == (d, bits) and R.dtype == np.float32
    np.testing.assert_array_equal(projection_matrix(d, bits, 3, "orthogonal"), R)   # regenerated, not stored
    for start in range(0, bits, d):
        block, gauss = R[:, start : start + d].astype(np.float64), G[:, start : start + d].astype(np.float64)
        # Orthogonal columns of length √d, spanning what the Gaussian block's first columns span (QR).
        np.testing.assert_allclose(block.T @ block, d * np.eye(block.shape[1]), atol=1e-3 * d)
        np.testing.assert_allclose(abs(block[:, 0] @ gauss[:, 0]), np.sqrt(d) * np.linalg.norm(gauss[:, 0]), rtol=1e-5)
    with pytest.raises(InvalidParameterError, match="projection"):
        projection_matrix(d, bits, 3, "sparse")


def test_a_model_file_without_a_projection_loads_with_the_gaussian_one(pair, tmp_path) -> None:
    from btel.core.modelfile import load_arrays, save_arrays

    X, Q = pair
    gaussian = LSHLocalizer(budget=8_000, projection="gaussian").fit(X)
    path = gaussian.save(tmp_path / "g.npz")
    # A file written before projections were recorded: neither the parameter nor the state names one.
    arrays, header = load_arrays(path)
    header["params"].pop("projection")
    header["state"].pop("projection")
    old = save_arrays(tmp_path / "old.npz", arrays, header)
    again = btel.load(old)
    assert again.projection == "gaussian"
    R = projection_matrix(64, gaussian.n_bits_, 0, "gaussian")
    np.testing.assert_array_equal(again.projection_.matrix(), R)
    np.testing.assert_array_equal(again.search(Q, 5)[1], gaussian.search(Q, 5)[1])
    # A state that contradicts the parameters is a damaged file.
    header["params"]["projection"], header["state"]["projection"] = "hadamard", "gaussian"
    with pytest.raises(btel.exceptions.ModelFileError, match="projection"):
        btel.load(save_arrays(tmp_path / "bad.npz", arrays, header))
    header["params"].pop("projection")
    header["state"]["projection"] = "sparse"
    with pytest.raises(btel.exceptions.ModelFileError, match="projection"):
        btel.load(save_arrays(tmp_path / "bad2.npz", arrays, header))


def test_hamming_scoring_is_minus_the_hamming_distance(pair) -> None:
    X, Q = pair
    model = LSHLocalizer(n_bits=64, scoring="hamming").fit(X)
    codes_q = np.unpackbits(np.packbits(model._project(btel.core.frontend.normalize_rows(Q[:3])) > 0, axis=1), axis=1)
    codes_x = np.unpackbits(model.codes_, axis=1)
    dist = (codes_q[:, None, :] != codes_x[None]).sum(axis=2)
    scores, places = model.search(Q[:3], 4)
    np.testing.assert_array_equal(-scores, np.take_along_axis(dist, places, axis=1))


@pytest.mark.parametrize("scoring", ["asymmetric", "hamming"])
@pytest.mark.parametrize("n_bits", [13, 64, 203])
def test_any_bit_count_is_stored_as_one_dense_stream_and_round_trips(pair, scoring, n_bits, tmp_path) -> None:
    from btel.methods.baselines.lsh import code_bytes

    X, Q = pair
    model = LSHLocalizer(n_bits=n_bits, scoring=scoring, center=False).fit(X)
    stored = model.storage_breakdown()["codes"]
    assert stored == code_bytes(400, n_bits) == -(-400 * n_bits // 8)
    # Row i's bits are bits i·P … (i+1)·P − 1 of the stream, the signs of its projection.
    with np.load(model.save(tmp_path / "m.npz"), allow_pickle=False) as z:
        stream = np.unpackbits(z["codes"].ravel(), count=400 * n_bits).reshape(400, n_bits)
    np.testing.assert_array_equal(stream, model._project(btel.core.frontend.normalize_rows(X)) > 0)
    again = btel.load(tmp_path / "m.npz")
    np.testing.assert_array_equal(again.codes_, model.codes_)
    np.testing.assert_array_equal(again.search(Q, 5)[0], model.search(Q, 5)[0])
    np.testing.assert_array_equal(again.search(Q, 5)[1], model.search(Q, 5)[1])


@given(n_rows=st.integers(1, 70_000), n_bits=st.integers(8, 100), seed=st.integers(0, 2**31 - 1))
@settings(max_examples=25, deadline=None)
def test_dense_stream_and_row_codes_are_inverse(n_rows: int, n_bits: int, seed: int) -> None:
    from btel.methods.baselines.lsh import code_bytes, dense_codes, row_codes

    rows = np.packbits(np.random.default_rng(seed).integers(0, 2, size=(n_rows, n_bits), dtype=np.uint8), axis=1)
    stream = dense_codes(rows, n_bits)
    assert stream.size == code_bytes(n_rows, n_bits)
    back = stream if n_bits % 8 == 0 else row_codes(stream, n_rows, n_bits)
    np.testing.assert_array_equal(back, rows)


def test_a_dense_stream_of_the_wrong_length_or_rows_is_refused(pair, tmp_path) -> None:
    from btel.core.modelfile import load_arrays, save_arrays

    X, _ = pair
    arrays, header = load_arrays(LSHLocalizer(n_bits=13).fit(X).save(tmp_path / "m.npz"))
    with pytest.raises(btel.exceptions.ModelFileError, match="codes"):
        btel.load(save_arrays(tmp_path / "short.npz", {**arrays, "codes": arrays["codes"][:-1]}, header))
    header["state"]["n_rows"] = 399  # the stream then has one byte too many
    with pytest.raises(btel.exceptions.ModelFileError, match="codes"):
        btel.load(save_arrays(tmp_path / "rows.npz", arrays, header))
    arrays, header = load_arrays(LSHLocalizer(n_bits=16).fit(X).save(tmp_path / "m16.npz"))
    header["state"]["n_rows"] = 401
    with pytest.raises(btel.exceptions.ModelFileError, match="codes"):
        btel.load(save_arrays(tmp_path / "rows16.npz", arrays, header))
    for bad in ("400", 0, True, 2.5, 2**41):
        header["state"]["n_rows"] = bad
        with pytest.raises(btel.exceptions.ModelFileError, match="n_rows"):
            btel.load(save_arrays(tmp_path / "bad.npz", arrays, header))


def test_errors_name_the_fix(pair) -> None:
    X, _ = pair
    with pytest.raises(BudgetTooSmallError, match="LSH") as info:
        make_method("lsh", budget=300, center=True).fit(X)
    assert info.value.minimum == 400 + 2 * 64
    with pytest.raises(BudgetTooSmallError, match="LSH") as info:
        make_method("lsh", budget=300).fit(X)
    assert info.value.minimum == 400
    with pytest.raises(InvalidParameterError, match="n_bits"):
        LSHLocalizer(n_bits=4).fit(X)
    with pytest.raises(InvalidParameterError, match="scoring"):
        make_method("lsh", scoring="cosine")


@pytest.mark.realdata
def test_gardens_point_asymmetric_lsh_beats_hamming_and_approaches_brute_force(gardenspoint_netvlad) -> None:
    X, Q = gardenspoint_netvlad
    truth = np.arange(Q.shape[0])

    def r2(model):
        return float((np.abs(model.fit(X).predict(Q) - truth) <= 2).mean())

    asym, ham = r2(make_method("lsh", budget="32KB")), r2(make_method("lsh", budget="32KB", scoring="hamming"))
    brute = r2(make_method("bruteforce"))
    # Measured: 0.430 / 0.415 / 0.480 (btel experiment frontier has every budget).
    assert asym >= ham and asym >= 0.85 * brute


# ----------------------------------------------------------------------------- the scan of packed codes
def _reference(model, Q):
    """(qR) · sign(x_i R) from unpacked codes: the asymmetric score of every row (qR on the scans' grid)."""
    from btel.methods.baselines.signscan import query_rows

    P = query_rows(model._project(btel.core.frontend.normalize_rows(Q)), model.codes_.shape[1])[:, : model.n_bits_]
    return P.astype(np.float64) @ (np.unpackbits(model.codes_, axis=1, count=model.n_bits_) * 2.0 - 1).T


def test_a_query_s_answer_does_not_depend_on_its_batch() -> None:
    """Rows with the same code tie exactly in every scan: alone or in a batch, the lower row answers."""
    X = np.random.default_rng(3).normal(size=(300, 3)).astype(np.float32)
    X[[40, 41]] = X[7] * np.float32(1.0001)  # the same direction: the same codes as row 7
    model = LSHLocalizer(n_bits=256).fit(X)
    Q = X[:20]
    batch = model.predict(Q)
    same = np.flatnonzero((model.codes_ == model.codes_[7]).all(axis=1))   # every row tied with row 7
    assert {7, 40, 41} <= set(same.tolist()) and batch[7] == same.min()
    np.testing.assert_array_equal(batch, [model.predict(q[None])[0] for q in Q])


@pytest.mark.parametrize("n_bits", [13, 64, 203])
@pytest.mark.parametrize("n_queries", [1, 40])
def test_search_and_place_scores_are_the_asymmetric_scores_of_the_packed_codes(pair, n_bits, n_queries,
                                                                               monkeypatch) -> None:
    """Through the model (front end, projection, padding to whole bytes): both scans of
    :mod:`btel.methods.baselines.signscan`, with its blocks at their size and tiny."""
    from btel.methods.baselines import signscan

    X, Q = pair
    model = LSHLocalizer(n_bits=n_bits, center=False).fit(X)
    reference = _reference(model, Q[:n_queries])
    for block_values in (signscan.BLOCK_VALUES, 1 << 10):
        monkeypatch.setattr(signscan, "BLOCK_VALUES", block_values)
        scores, places = model.search(Q[:n_queries], 7)
        np.testing.assert_allclose(scores, np.take_along_axis(reference, places, axis=1), atol=1e-4)
        np.testing.assert_allclose(scores[:, -1], np.sort(reference, axis=1)[:, -7], atol=1e-4)
        np.testing.assert_allclose(model.place_scores(Q[:n_queries]), reference, atol=1e-4)


def test_a_loaded_model_holds_its_codes_and_a_bounded_block_not_a_float_copy(tmp_path) -> None:
    """4 MB of codes: a float32 ±1 copy would take 134 MB; load and search stay within stored + 64 MB."""
    import tracemalloc

    rng = np.random.default_rng(1)
    X = rng.normal(size=(32_768, 64)).astype(np.float32)
    model = LSHLocalizer(n_bits=1024, center=False).fit(X)
    path = model.save(tmp_path / "big.npz")
    stored = model.nbytes
    del model
    tracemalloc.start()
    try:
        again = btel.load(path)
        after_load = tracemalloc.get_traced_memory()[0]
        again.predict(X[:1])
        again.search(X[:64], 5)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert after_load <= stored + (1 << 20)   # the codes and little else
    assert peak <= stored + (64 << 20)


def test_a_budget_is_refused_from_the_shapes_before_the_map_is_transformed() -> None:
    """The planner runs on (N, d) first: refusing 8 KB for 100,000 rows allocates no normalised copy of X."""
    import tracemalloc

    X = np.ones((100_000, 128), dtype=np.float32)   # 51 MB
    X[:, 0] = np.arange(100_000)                      # rows that differ (a map of one repeated row is refused)
    tracemalloc.start()
    try:
        with pytest.raises(BudgetTooSmallError) as info:
            LSHLocalizer(budget="8KB").fit(X)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert info.value.minimum == 100_000 and peak < 4 << 20


@pytest.mark.parametrize("method, n_rows, d, budget", [("lsh", 500, 8192, "1MB"), ("auto", 500, 8192, "1MB"),
                                                      ("lsh", 2000, 12288, "256KB")])
def test_near_duplicate_queries_of_wide_descriptors_are_found(method, n_rows, d, budget, tmp_path) -> None:
    """Rows sharing a common direction and a low-rank part; queries are the rows plus noise (cosine ≈ 0.93
    to their own row against ≈ 0.6 to the nearest other). Found after a save and a load."""
    rng = np.random.default_rng(d)
    X = rng.standard_normal((n_rows, d), dtype=np.float32)
    X *= 0.6
    X += rng.standard_normal(d, dtype=np.float32)
    factors = rng.standard_normal((n_rows, 64), dtype=np.float32)
    X += 0.075 * (factors @ rng.standard_normal((64, d), dtype=np.float32))
    Q = X + 0.5 * rng.standard_normal((n_rows, d), dtype=np.float32)
    model = btel.load(make_method(method, budget=budget).fit(X).save(tmp_path / "m.npz"))
    assert model.nbytes <= btel.core.storage.parse_budget(budget)
    assert (model.predict(Q) == np.arange(n_rows)).mean() >= 0.9


def test_a_model_file_with_orthogonal_blocks_loads_and_answers_as_it_was_fitted(pair, tmp_path) -> None:
    X, Q = pair
    model = LSHLocalizer(budget=8_000, projection="orthogonal").fit(X)
    again = btel.load(model.save(tmp_path / "o.npz"))
    assert again.projection == "orthogonal"
    R = projection_matrix(64, model.n_bits_, 0, "orthogonal")
    np.testing.assert_array_equal(again.projection_.matrix(), R)
    np.testing.assert_array_equal(again.search(Q, 5)[1], model.search(Q, 5)[1])


@pytest.mark.parametrize("n_rows, d", [(200, 16), (50, 100)])
def test_bits_stop_at_16_d_and_the_model_says_the_rest_of_the_budget_is_unused(n_rows, d) -> None:
    X = np.random.default_rng(d).normal(size=(n_rows, d)).astype(np.float32)
    capped = LSHLocalizer(budget=n_rows * 4 * d).fit(X)           # room for 32·d bits per row
    assert capped.n_bits_ == 16 * d and capped.budget_saturated()
    assert capped.unused_budget() == n_rows * 4 * d - capped.nbytes > 0
    assert f"{capped.unused_budget()} B unused" in capped.summary()
    filled = LSHLocalizer(budget=n_rows * d).fit(X)               # 8·d bits per row: all spent
    assert filled.n_bits_ == 8 * d and not filled.budget_saturated() and filled.unused_budget() == 0
    assert not LSHLocalizer(budget=n_rows * 4 * d, n_bits=64).fit(X).budget_saturated()   # pinned: never


def _recall(pred: np.ndarray, tolerance: int) -> float:
    return float(np.mean(np.abs(pred - np.arange(pred.shape[0])) <= tolerance))


@pytest.mark.realdata
@pytest.mark.parametrize("data", ["gardens-point", "nordland-hog", "synthetic-route",
                                  "synthetic-independent"])
def test_lsh_with_4d_bits_is_within_002_of_brute_force_on_the_same_front_end(data, request) -> None:
    """Approximations converge: asymmetric LSH at 4·d bits per row (mean of seeds 0–2) against cosine."""
    if data == "gardens-point":
        X, Q = request.getfixturevalue("gardenspoint_netvlad")
        tolerance = 2
    elif data == "nordland-hog":
        summer, winter = request.getfixturevalue("nordland_hog")
        rows = np.arange(0, summer.shape[0], 20)     # every 20th frame: 179 places, recall within 1
        X, Q, tolerance = summer[rows], winter[rows], 1
    else:
        from btel.datasets import synthetic_route

        route = synthetic_route(1000, 256, condition_shift=1.0, seed=11)
        independent = data == "synthetic-independent"
        perm = np.random.default_rng(1).permutation(1000) if independent else np.arange(1000)
        X, Q, tolerance = route.map[perm], route.queries[perm], (0 if independent else 2)
    d = X.shape[1]
    exact = _recall(make_method("bruteforce").fit(X).predict(Q), tolerance)
    budget = X.shape[0] * d // 2                 # 4·d bits per row
    lsh = np.mean([_recall(LSHLocalizer(budget=budget, random_state=seed).fit(X).predict(Q), tolerance)
                   for seed in range(3)])
    assert abs(lsh - exact) <= 0.02, (lsh, exact)


@pytest.mark.parametrize("center", [False, True])
def test_the_l2_map_reaches_the_fit_unscaled_with_the_codes_of_a_normalised_copy(center, monkeypatch,
                                                                                 map_types) -> None:
    from btel.core.rows import ScaledRows
    from btel.datasets import synthetic_route

    route = synthetic_route(n_places=800, dim=48, seed=4)
    seen = map_types(LSHLocalizer, "_fit_rows")
    lazy = LSHLocalizer(budget="8KB", center=center, random_state=0).fit(route.map)
    assert seen == [ScaledRows.__name__]  # no normalised copy of the map was made before the fit
    monkeypatch.setattr(LSHLocalizer, "_fit_reads_row_blocks", False)
    eager = LSHLocalizer(budget="8KB", center=center, random_state=0).fit(route.map)
    assert seen[-1] == "ndarray"
    assert lazy.n_bits_ == eager.n_bits_ and (lazy.mean_ is None) == (eager.mean_ is None)
    # Sign bits of the same projections of the same rows, scaled by float32 factors instead of divided:
    # equal but for values that round across zero.
    assert np.mean(np.unpackbits(lazy.codes_) == np.unpackbits(eager.codes_)) >= 0.999
    assert np.mean(lazy.predict(route.queries) == eager.predict(route.queries)) >= 0.99
