"""CodeLocalizer (btel-codes): exact decoding of learnable routes, budgets, files, decoders, solvers."""

from __future__ import annotations

import json

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from btel import load
from btel.methods.codes.planning import code_planned_bytes, plan_codes
from btel.methods.codes.codebook import FAMILIES, Codebook
from btel.methods.codes.estimator import CodeLocalizer
from btel.datasets import synthetic_route
from btel.exceptions import BudgetTooSmallError, InvalidParameterError, ModelFileError
from btel.methods import make_method
from btel.core.modelfile import load_arrays, save_arrays


@pytest.fixture(scope="module")
def learnable() -> tuple[np.ndarray, np.ndarray]:
    """A route whose queries are the map plus 5 % noise (N = 300 < d = 384: every labelling is linear)."""
    route = synthetic_route(300, 384, noise=0.05, condition_shift=0.0, seed=4)
    return route.map, route.queries


@pytest.fixture(scope="module")
def harder() -> tuple[np.ndarray, np.ndarray]:
    route = synthetic_route(600, 64, condition_shift=0.5, seed=5)
    return route.map, route.queries


@pytest.mark.parametrize("family", FAMILIES)
def test_every_family_decodes_a_learnable_route_exactly(family: str, learnable) -> None:
    X, Q = learnable
    model = CodeLocalizer(code=family, n_codes=None if family == "binary" else 64).fit(X)
    pred = model.predict(Q)
    # The binary code has no redundant column, so every bit the ridge misses is a wrong place: under the
    # α rule's ρ = 0.1 (set for changes of condition, btel.methods.codes.solvers) it decodes 0.92 of this
    # route exactly (0.98 at ρ = 0.03); the redundant families stay at 1.00.
    assert np.mean(pred == np.arange(300)) >= (0.9 if family == "binary" else 0.99), family


@pytest.mark.parametrize("bits", [32, 16, 8, 4])
def test_file_size_is_the_counted_bytes_and_the_model_round_trips_exactly(bits: int, harder, tmp_path) -> None:
    X, Q = harder
    model = CodeLocalizer(n_codes=100, n_features=40, weight_bits=bits).fit(X)
    assert model.nbytes == code_planned_bytes(100, 40, 64, bits)
    path = model.save(tmp_path / "m.btel.npz")
    assert 0 <= path.stat().st_size - model.nbytes <= 4096
    again = load(path)
    for name, array in model._stored_arrays().items():
        stored = again._stored_arrays()[name]
        assert stored.dtype == array.dtype and np.array_equal(stored, array), name
    assert again.codebook_ == model.codebook_
    np.testing.assert_array_equal(again.codebook_.codewords(np.arange(600)), model.codebook_.codewords(np.arange(600)))
    np.testing.assert_array_equal(again.place_scores(Q[:50]), model.place_scores(Q[:50]))
    np.testing.assert_array_equal(again.predict(Q), model.predict(Q))
    assert again.summary() == model.summary()


def test_codewords_regenerate_from_the_header_not_the_arrays(harder, tmp_path) -> None:
    X, _ = harder
    model = CodeLocalizer(n_codes=32, random_state=None).fit(X)  # a drawn seed, recorded in the file
    arrays, header = load_arrays(model.save(tmp_path / "m.npz"))
    assert header["state"]["code_seed"] == model.code_seed_
    assert not any(a.shape[0] == 600 for a in arrays.values())  # no codebook stored
    assert load(tmp_path / "m.npz").codebook_ == Codebook("periodic", 600, 32, model.code_seed_)


@settings(max_examples=25, deadline=None)
@given(budget=st.integers(50, 200_000), d=st.integers(1, 5000), n=st.integers(2, 10**7),
       family=st.sampled_from(FAMILIES), bits=st.sampled_from([None, 4, 8, 16, 32]))
def test_the_planner_never_exceeds_the_budget(budget, d, n, family, bits) -> None:
    try:
        plan = plan_codes(budget, d, n, family, bits=bits)
    except BudgetTooSmallError as exc:
        assert exc.minimum > budget
        return
    assert plan.nbytes == code_planned_bytes(plan.n_codes, plan.n_selected, d, plan.bits) <= budget
    if family not in ("binary", "offset") and plan.n_selected < d:
        assert plan.n_codes >= plan.n_selected  # the square rule: K = d' until d' = d, then the rest to K


@settings(max_examples=15, deadline=None)
@given(budget=st.integers(100, 60_000), family=st.sampled_from(FAMILIES))
def test_fitted_models_fill_but_never_exceed_the_budget(budget, family, harder) -> None:
    X, _ = harder
    model = CodeLocalizer(code=family, budget=budget)
    try:
        model.fit(X)
    except BudgetTooSmallError as exc:
        assert exc.minimum > budget
        return
    assert model.nbytes == model.plan_.nbytes <= budget
    assert sum(model.storage_breakdown().values()) == model.nbytes


def test_the_minimum_is_exact(harder) -> None:
    X, _ = harder
    with pytest.raises(BudgetTooSmallError) as info:
        CodeLocalizer(budget=20).fit(X)
    minimum = info.value.minimum
    CodeLocalizer(budget=minimum).fit(X)
    with pytest.raises(BudgetTooSmallError):
        CodeLocalizer(budget=minimum - 1).fit(X)


def test_the_planner_fills_a_budget_with_the_square_rule() -> None:
    plan = plan_codes(32_000, 500, 200, "periodic")
    assert plan.bits == 4 and abs(plan.n_codes - plan.n_selected) <= 3 and plan.nbytes > 31_500
    wide = plan_codes(1_000_000, 500, 200, "periodic")
    assert wide.n_selected == 500 and wide.n_codes > 3000 and wide.nbytes > 990_000
    assert plan_codes(64_000, 500, 200, "binary").n_codes == 8
    assert plan_codes(64_000, 500, 200, "periodic", n_codes=100).n_codes == 100
    assert plan_codes(64_000, 500, 200, "periodic", n_selected=50).n_selected == 50
    assert plan_codes(64_000, 500, 200, "periodic", bits=32).bits == 32
    assert "square rule" in plan.describe()


@settings(max_examples=20, deadline=None)
@given(rows=st.integers(1, 20), scale=st.floats(1e-3, 1e6), seed=st.integers(0, 1000),
       decode=st.sampled_from(["exact", "coarse"]))
def test_decoded_indices_are_always_places(rows, scale, seed, decode, harder) -> None:
    X, _ = harder
    model = _fitted(X, decode)
    Q = np.random.default_rng(seed).normal(scale=scale, size=(rows, X.shape[1])).astype(np.float32)
    pred = model.predict(Q)
    assert pred.dtype == np.int64 and pred.shape == (rows,)
    assert pred.min() >= 0 and pred.max() < 600
    ranked = model.rank(Q, 7)
    assert ranked.min() >= 0 and ranked.max() < 600 and all(len(set(r)) == 7 for r in ranked.tolist())


_MODELS: dict[str, CodeLocalizer] = {}


def _fitted(X: np.ndarray, decode: str) -> CodeLocalizer:
    if decode not in _MODELS:
        _MODELS[decode] = CodeLocalizer(n_codes=64, decode=decode, coarse_block=10, coarse_candidates=4).fit(X)
    return _MODELS[decode]


def test_exact_decode_is_the_argmax_of_place_scores(harder) -> None:
    X, Q = harder
    model = CodeLocalizer(n_codes=64).fit(X)
    scores = model.place_scores(Q)
    np.testing.assert_array_equal(model.predict(Q), np.argmax(scores, axis=1))
    np.testing.assert_array_equal(model.rank(Q, 5)[:, 0], model.predict(Q))
    np.testing.assert_allclose(scores, model.decision_function(Q).astype(np.float64)
                               @ model.codebook_.codewords(np.arange(600)).T.astype(np.float64), rtol=1e-4, atol=1e-3)


def test_coarse_decode_equals_exact_when_every_block_is_refined_and_loses_little_otherwise(harder) -> None:
    X, Q = harder
    exact = CodeLocalizer(n_codes=128, decode="exact").fit(X)
    full = CodeLocalizer(n_codes=128, decode="coarse", coarse_block=8, coarse_candidates=75).fit(X)
    np.testing.assert_array_equal(full.predict(Q), exact.predict(Q))
    coarse = CodeLocalizer(n_codes=128, decode="coarse", coarse_block=16, coarse_candidates=8).fit(X)
    truth = np.arange(600)
    hits_exact = np.mean(np.abs(exact.predict(Q) - truth) <= 10)
    hits_coarse = np.mean(np.abs(coarse.predict(Q) - truth) <= 10)
    agree = np.mean(coarse.predict(Q) == exact.predict(Q))
    assert hits_coarse >= hits_exact - 0.05 and agree >= 0.8, (hits_exact, hits_coarse, agree)


def test_block_means_are_the_means_of_the_codewords(harder) -> None:
    X, _ = harder
    model = CodeLocalizer(n_codes=24, coarse_block=7).fit(X)  # 600 = 85 × 7 + 5: a short last block
    codes = model.codebook_.codewords(np.arange(600)).astype(np.float64)
    expected = np.array([codes[i : i + 7].mean(axis=0) for i in range(0, 600, 7)])
    np.testing.assert_allclose(model._codewords.block_means(model._coarse_shape()[0]), expected, atol=1e-6)


@settings(max_examples=40, deadline=None)
@given(family=st.sampled_from(FAMILIES), n_places=st.integers(2, 2500), k=st.integers(8, 40),
       block=st.one_of(st.just(1), st.integers(1, 12), st.integers(1, 3000)), seed=st.integers(0, 2**32 - 1))
def test_block_means_equal_float32_sums_of_the_codewords_bit_for_bit(family, n_places, k, block, seed) -> None:
    from btel.methods.codes.codewords import Codewords

    k = int(np.ceil(np.log2(n_places))) if family in ("binary", "offset") else max(k, int(np.ceil(np.log2(n_places))))
    book = Codebook(family, n_places, k, seed)
    codes = book.codewords(np.arange(n_places)).astype(np.float32)
    starts = np.arange(0, n_places, block)
    counts = np.diff(np.append(starts, n_places)).astype(np.float32)
    expected = np.add.reduceat(codes, starts, axis=0) / counts[:, None]  # float32 throughout
    means = Codewords(book).block_means(block)
    assert means.dtype == np.float32 and means.shape == (starts.size, 8 * -(-k // 8))
    np.testing.assert_array_equal(means[:, :k], expected)
    assert np.all(means[:, k:] == 1)


def test_coarse_decode_needs_a_route_family() -> None:
    with pytest.raises(InvalidParameterError, match="decode='exact'"):
        CodeLocalizer(code="random", decode="coarse").fit(np.random.default_rng(0).normal(size=(50, 8)))


def test_sequence_decoders_and_streaming_work_on_the_codes(harder) -> None:
    X, Q = harder
    model = CodeLocalizer(budget="8KB").fit(X)
    truth = np.arange(600)
    single = np.mean(np.abs(model.predict(Q) - truth) <= 10)
    hmm = np.mean(np.abs(model.predict_sequence(Q, "hmm") - truth) <= 10)
    median = model.predict_sequence(Q, "median", window=5)
    assert median.shape == (600,) and hmm >= single
    stream = model.stream()
    for j in (0, 1, 2):
        np.testing.assert_array_equal(stream.search(Q[j], 3)[1], model.search(Q[j : j + 1], 3)[1][0])


def test_ridge_columns_fitted_in_parallel_equal_a_serial_fit() -> None:
    route = synthetic_route(3000, 32, seed=2)  # more rows than columns: the primal path, column groups
    serial = CodeLocalizer(n_codes=256).fit(route.map)
    threads = CodeLocalizer(n_codes=256, n_jobs=2).fit(route.map)
    np.testing.assert_allclose(threads.weights_.dequantise(), serial.weights_.dequantise(), rtol=0, atol=1e-4)
    assert np.mean(threads.predict(route.queries) == serial.predict(route.queries)) > 0.99


def test_primal_and_dual_ridge_agree() -> None:
    from btel.methods.codes.solvers import fit_ridge_codes

    X = np.random.default_rng(0).normal(size=(40, 30)).astype(np.float32)
    book = Codebook("periodic", 40, 16)
    primal = fit_ridge_codes(X, np.arange(30), book, None, alpha=0.5)  # 40 rows > 30 columns: primal
    # The same problem through the dual (kernel) form: 40 rows ≤ 60 columns, the extra ones zero.
    wide = np.concatenate([X, np.zeros((40, 30), np.float32)], axis=1)
    kernel = fit_ridge_codes(wide, np.arange(60), book, None, alpha=0.5)
    np.testing.assert_allclose(kernel.weights[:, :30], primal.weights, atol=1e-8)
    np.testing.assert_allclose(kernel.weights[:, 30:], 0, atol=1e-12)
    np.testing.assert_allclose(kernel.offsets, primal.offsets)
    np.testing.assert_allclose(kernel.center[:30], primal.center)


def test_liblinear_solver_and_fixed_alpha(harder) -> None:
    X, Q = harder
    svm = CodeLocalizer(n_codes=32, solver="liblinear").fit(X)
    assert svm.alpha_ is None and "liblinear" in svm.summary()
    ridge = CodeLocalizer(n_codes=32, alpha=0.5).fit(X)
    assert ridge.alpha_ == 0.5
    truth = np.arange(600)
    for model in (svm, ridge):
        assert np.mean(np.abs(model.predict(Q) - truth) <= 10) > 0.3


def test_registry_entry_is_budget_filling_codes_of_the_family_the_map_asks_for(harder) -> None:
    X, _ = harder   # a synthetic route: an ordered map (continuity ≈ 0.9)
    model = make_method("btel-codes", budget="16KB").fit(X)
    assert model.code == "auto" and model.code_ == "periodic" and 15_000 < model.nbytes <= 16_000
    shuffled = make_method("btel-codes", budget="16KB").fit(X[np.random.default_rng(0).permutation(len(X))])
    assert shuffled.code_ == "random" and 15_000 < shuffled.nbytes <= 16_000
    assert "btel-codes" in __import__("btel.methods", fromlist=["DESCRIPTIONS"]).DESCRIPTIONS


def test_tampered_files_are_refused(harder, tmp_path) -> None:
    X, _ = harder
    path = CodeLocalizer(n_codes=32, n_features=20).fit(X).save(tmp_path / "m.npz")
    arrays, header = load_arrays(path)

    def rewrite(arrays, header) -> None:
        save_arrays(tmp_path / "bad.npz", arrays, {k: v for k, v in header.items() if k not in ("format",
                                                                                                  "format_version")})

    bad = json.loads(json.dumps(header))
    bad["state"]["n_codes"] = 33
    rewrite(arrays, bad)
    with pytest.raises(ModelFileError):
        load(tmp_path / "bad.npz")
    bad = json.loads(json.dumps(header))
    bad["params"]["code"] = "binary"  # K = 32 is not a binary code of 600 places
    rewrite(arrays, bad)
    with pytest.raises(ModelFileError):
        load(tmp_path / "bad.npz")
    rewrite({**arrays, "columns": arrays["columns"][::-1].copy()}, header)
    with pytest.raises(ModelFileError, match="columns"):
        load(tmp_path / "bad.npz")
    rewrite({**arrays, "scales": -arrays["scales"]}, header)
    with pytest.raises(ModelFileError, match="scales"):
        load(tmp_path / "bad.npz")


@pytest.mark.realdata
def test_gardens_point_day_to_night_at_32kb(gardenspoint_netvlad) -> None:
    """Measured 0.615 / 0.865 (recall within 2 / 10 frames) at 32 KB; PQ 0.340 / 0.675 at the same budget."""
    X, Q = gardenspoint_netvlad
    truth = np.arange(200)
    codes = make_method("btel-codes", budget="32KB").fit(X)
    pq = make_method("pq", budget="32KB").fit(X)
    within = {name: [np.mean(np.abs(m.predict(Q) - truth) <= t) for t in (2, 10)]
              for name, m in (("codes", codes), ("pq", pq))}
    assert codes.nbytes <= 32_000
    assert within["codes"][0] >= 0.55 and within["codes"][1] >= 0.82, within
    assert within["codes"][0] > within["pq"][0] and within["codes"][1] > within["pq"][1], within


@pytest.mark.slow
@pytest.mark.parametrize("backend", ["loky", "dask"])
def test_ridge_on_worker_processes_and_dask_equals_a_serial_fit(backend: str) -> None:
    route = synthetic_route(2000, 32, seed=2)  # the primal path: column groups are separate tasks
    serial = CodeLocalizer(n_codes=192).fit(route.map)
    if backend == "dask":
        distributed = pytest.importorskip("distributed")
        with distributed.LocalCluster(n_workers=1, threads_per_worker=2, processes=False,
                                      dashboard_address=":0") as cluster, distributed.Client(cluster):
            remote = CodeLocalizer(n_codes=192, backend="dask", n_jobs=2).fit(route.map)
    else:
        remote = CodeLocalizer(n_codes=192, backend="loky", n_jobs=2).fit(route.map)
    np.testing.assert_allclose(remote.weights_.dequantise(), serial.weights_.dequantise(), rtol=0, atol=1e-4)
    assert np.mean(remote.predict(route.queries) == serial.predict(route.queries)) > 0.99


def test_targets_are_read_off_the_btel_codes_rows_only() -> None:
    from btel.experiments.codes import check_targets

    def row(method, budget, r2, r10, family="codes"):
        return {"part": "gardens-point", "status": "ok", "method": method, "budget": budget, "nbytes": budget,
                "family": family, "recall@2": r2, "recall@10": r10}

    rows = [row("btel-codes", 32_000, 0.55, 0.79), row("codes random 4-bit", 32_000, 0.9, 0.9),
            row("btel-codes", 64_000, 0.63, 0.85), row("PQ", 64_000, 0.64, 0.7, "quantiser"),
            row("brute force", None, 0.48, 0.75, "reference")]
    rows[-1]["nbytes"] = 400_000
    verdicts = {t["target"]: t for t in check_targets(rows)}
    assert verdicts["≤ 32 KB: R@2 ≥ 0.50"]["met"] and not verdicts["≤ 32 KB: R@10 ≥ 0.80"]["met"]
    assert verdicts["≤ 64 KB: R@2 ≥ 0.62"]["met"]
    versus = verdicts["every budget 4–64 KB: btel-codes ≥ best of PQ/OPQ/ITQ (recall@2)"]
    assert not versus["met"] and [v["met"] for v in versus["per_budget"]] == [True, False]


@pytest.fixture(scope="module")
def walk() -> tuple[np.ndarray, np.ndarray]:
    """A random-walk route (neighbouring places look alike: route share 1.0; permuted 0.005)."""
    rng = np.random.default_rng(0)
    X = np.cumsum(rng.normal(size=(600, 64)), axis=0).astype(np.float32)
    return X, (X + rng.normal(scale=0.5, size=X.shape)).astype(np.float32)


def test_the_default_code_family_is_read_from_the_map_on_nordland_and_gardens_point(nordland_hog,
                                                                                   gardenspoint_netvlad) -> None:
    """Real data: btel-codes' default (code='auto') takes periodic codes on Nordland HOG (an ordered map:
    share 0.27, continuity 0.68) and on Gardens Point (a route), random codes on Gardens Point permuted;
    on Nordland the periodic codes are the better family (frontier: recall@10 0.025 vs 0.008 at 4 KB)."""
    from btel.evaluation.metrics import recall_at_tolerance

    summer, winter = nordland_hog
    model = CodeLocalizer(budget="4KB", random_state=0).fit(summer)
    assert model.code == "auto" and model.code_ == "periodic" and "ordered map" in model.code_reason_
    random = CodeLocalizer(code="random", budget="4KB", random_state=0).fit(summer)
    truth = np.arange(summer.shape[0])
    ours, theirs = (recall_at_tolerance(m.predict(winter), truth, (10,))[10] for m in (model, random))
    assert ours > 2 * theirs
    day, _night = gardenspoint_netvlad
    assert CodeLocalizer(budget="8KB", random_state=0).fit(day).code_ == "periodic"
    perm = np.random.default_rng(0).permutation(day.shape[0])
    assert CodeLocalizer(budget="8KB", random_state=0).fit(day[perm]).code_ == "random"


def test_code_auto_picks_periodic_on_a_route_and_random_on_independent_places(walk, tmp_path) -> None:
    X, Q = walk
    perm = np.random.default_rng(0).permutation(X.shape[0])
    route = CodeLocalizer(code="auto", budget="16KB", random_state=0).fit(X)
    independent = CodeLocalizer(code="auto", budget="16KB", random_state=0).fit(X[perm])
    assert route.code_ == "periodic" and independent.code_ == "random"
    assert "route share" in route.code_reason_ and "→ random" in independent.code_reason_
    assert "periodic codes [code='auto'" in route.summary()
    # The chosen family is what a fixed-family fit gives, and it survives the model file.
    fixed = CodeLocalizer(code="random", budget="16KB", random_state=0).fit(X[perm])
    np.testing.assert_array_equal(independent.predict(Q[perm]), fixed.predict(Q[perm]))
    path = independent.save(tmp_path / "m.npz")
    _, header = load_arrays(path)
    assert header["params"]["code"] == "auto" and header["state"]["code"] == "random"
    back = load(path)
    assert back.code == "auto" and back.code_ == "random" and back.code_reason_ == independent.code_reason_
    np.testing.assert_array_equal(back.predict(Q[perm]), independent.predict(Q[perm]))


def test_code_auto_files_with_a_bad_family_and_coarse_decode_on_independent_places_are_refused(walk,
                                                                                                tmp_path) -> None:
    X, _ = walk
    perm = np.random.default_rng(0).permutation(X.shape[0])
    with pytest.raises(InvalidParameterError, match="coarse"):
        CodeLocalizer(code="auto", decode="coarse", budget="16KB").fit(X[perm])
    path = CodeLocalizer(code="auto", n_codes=32, n_features=20).fit(X).save(tmp_path / "m.npz")
    arrays, header = load_arrays(path)
    header["state"]["code"] = "zigzag"
    save_arrays(tmp_path / "bad.npz", arrays, {k: v for k, v in header.items() if k not in ("format",
                                                                                             "format_version")})
    with pytest.raises(ModelFileError, match="code family"):
        load(tmp_path / "bad.npz")


def test_files_without_a_recorded_family_load_with_their_code_parameter(harder, tmp_path) -> None:
    X, Q = harder
    model = CodeLocalizer(code="periodic", n_codes=32, n_features=20).fit(X)
    arrays, header = load_arrays(model.save(tmp_path / "m.npz"))
    del header["state"]["code"], header["state"]["code_reason"]
    save_arrays(tmp_path / "old.npz", arrays, {k: v for k, v in header.items() if k not in ("format",
                                                                                             "format_version")})
    old = load(tmp_path / "old.npz")
    assert old.code_ == "periodic"
    np.testing.assert_array_equal(old.predict(Q), model.predict(Q))


@pytest.mark.realdata
def test_code_auto_on_gardens_point_and_the_same_rows_permuted(gardenspoint_netvlad) -> None:
    """Gardens Point is a route (periodic codes, recall@2 0.615 at 32 KB); permuted alike it is not."""
    X, Q = gardenspoint_netvlad
    perm = np.random.default_rng(0).permutation(X.shape[0])
    route = CodeLocalizer(code="auto", budget="32KB").fit(X)
    shuffled = CodeLocalizer(code="auto", budget="32KB").fit(X[perm])
    assert route.code_ == "periodic" and shuffled.code_ == "random"
    assert np.mean(np.abs(route.predict(Q) - np.arange(200)) <= 2) >= 0.55


def test_coarse_decode_answers_k_distinct_places_when_the_short_last_block_is_refined() -> None:
    # 600 = 85 × 7 + 5: the refined blocks may hold 3 × 7 + 5 = 26 places, fewer than 4 × 7 = 28.
    X = synthetic_route(600, 64, seed=4).map
    model = CodeLocalizer(n_codes=128, decode="coarse", coarse_block=7, coarse_candidates=4).fit(X)
    M = model._padded_margins(model._check_queries(X[-8:]))
    coarse = M @ model._codewords.block_means(7).T
    refined = (np.argsort(-coarse, axis=1)[:, :4] == 85).any(axis=1)  # queries whose short block is refined
    assert refined.sum() >= 3
    Q = X[-8:][refined]
    scores, places = model.search(Q, 28)
    assert places.shape == (len(Q), 28) and all(len(set(row)) == 28 for row in places.tolist())
    assert np.isfinite(scores).all()


@pytest.mark.parametrize("solver", ["ridge", "liblinear"])
def test_the_l2_map_reaches_the_fit_unscaled_with_the_answers_of_a_normalised_copy(solver, monkeypatch,
                                                                                   map_types) -> None:
    from btel.core.rows import ScaledRows

    route = synthetic_route(n_places=600, dim=64, seed=3)
    seen = map_types(CodeLocalizer, "_fit")
    lazy = CodeLocalizer(budget="8KB", solver=solver, random_state=0).fit(route.map)
    assert seen == [ScaledRows.__name__]  # no normalised copy of the map was made before _fit
    monkeypatch.setattr(CodeLocalizer, "_fit_reads_row_blocks", False)
    eager = CodeLocalizer(budget="8KB", solver=solver, random_state=0).fit(route.map)
    assert seen[-1] == "ndarray"
    assert lazy.code_ == eager.code_ and lazy.n_codes_ == eager.n_codes_
    if solver == "ridge":
        assert lazy.alpha_ == pytest.approx(eager.alpha_, rel=1e-5)
    # The same ridge on rows scaled by float32 factors instead of divided: the same answers up to rounding.
    assert np.mean(lazy.predict(route.queries) == eager.predict(route.queries)) >= 0.99


def test_nordland_answers_from_codewords_filled_on_demand_equal_the_dense_codebooks(nordland_hog,
                                                                                  monkeypatch) -> None:
    """Real data: with the float32 codebook refused, the exact decode reads packed codewords filled on
    demand (runs of consecutive places, one add per element: btel.methods.codes.periodic) and answers
    Nordland's winter queries as the dense codebook does, the first query having generated only part of
    the map."""
    import btel.methods.codes.codebook as codebook
    import btel.methods.codes.codewords as codewords

    summer, winter = nordland_hog
    queries = winter[::25]
    dense = CodeLocalizer(code="periodic", budget="16KB", decode="exact", random_state=0).fit(summer)
    expected = dense.predict(queries)
    monkeypatch.setattr(codewords, "DENSE_CACHE_BYTES", 10)
    runs: list[int] = []  # the length of every run of consecutive places generated
    periodic_packed_run = codebook.periodic_packed_run

    def counted_run(*args, **kwargs):
        runs.append(args[3])
        return periodic_packed_run(*args, **kwargs)

    monkeypatch.setattr(codebook, "periodic_packed_run", counted_run)
    packed = CodeLocalizer(code="periodic", budget="16KB", decode="exact", random_state=0).fit(summer)
    assert packed.exact_path(1) == "bounded"
    first = packed.predict(queries[:1])
    filled = packed._codewords.filled
    assert filled is not None and 0 < filled.sum() < filled.size
    np.testing.assert_array_equal(first, expected[:1])
    np.testing.assert_array_equal(packed.predict(queries), expected)
    # Every filled place came from a run; a run bridges gaps of up to FILL_GAP filled places, no more.
    assert runs and filled.sum() <= sum(runs) <= filled.sum() + codewords.FILL_GAP * len(runs)
