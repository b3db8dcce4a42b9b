"""PQ, OPQ and ITQ: the budget rule, what is stored, and that the search is an exact scan over codes."""

from __future__ import annotations

import os

import faiss
import numpy as np
import pytest

from btel.methods.baselines import ITQLocalizer, OPQLocalizer, PQConfig, PQLocalizer, quiet_faiss
from btel.methods.baselines._common import faiss_threads
from btel.exceptions import BudgetTooSmallError, InvalidParameterError, NotEnoughPlacesError


@pytest.fixture(scope="module")
def data() -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(3)
    # Correlated descriptors (low-rank + noise), as real ones are: PCA has something to find.
    X = (rng.normal(size=(400, 12)) @ rng.normal(size=(12, 48)) + 0.3 * rng.normal(size=(400, 48))).astype(np.float32)
    Q = (X[:100] + 0.1 * rng.normal(size=(100, 48))).astype(np.float32)
    return X, Q


# -- the budget rule (pure arithmetic) ------------------------------------------------------------
def test_rule_reproduces_the_spec_reference_configuration():
    # SPEC §10: raw 3780-D HOG of 3576 frames, 500 KB → 140 sub-quantisers × 4 bits, no PCA, 492 KB.
    pq = PQLocalizer(budget="500KB")
    config = pq.choose_config(3576, 3780, 500_000)
    assert config == PQConfig(3780, 140, 4)
    assert pq.planned_bytes(3576, 3780, config=config) == 492_240
    # And the 28 × 4-bit point of the same paragraph (292 KB).
    pinned = PQLocalizer(n_subquantizers=28, nbits=4, pca_dim=3780)
    assert pinned.planned_bytes(3576, 3780, config=pinned.choose_config(3576, 3780, 292_000)) == 291_984


@pytest.mark.parametrize("always_project", [False, True], ids=["pq", "opq-rotation"])
@pytest.mark.parametrize("budget", [2_000, 20_000, 100_000, 2_000_000])
def test_rule_takes_the_most_code_bits_that_fit(always_project, budget):
    model = PQLocalizer()
    n_rows, d = 400, 48

    def planned(c):
        return model.planned_bytes(n_rows, d, config=c, always_project=always_project)

    chosen = model.choose_config(n_rows, d, budget, always_project=always_project)
    chosen_bytes = planned(chosen)
    assert chosen_bytes <= budget
    fitting = [c for c in model.candidates(n_rows, d, budget) if planned(c) <= budget]
    assert chosen in fitting
    assert chosen.code_bits == max(c.code_bits for c in fitting)
    ties = [c for c in fitting if c.code_bits == chosen.code_bits]
    assert chosen_bytes == min(planned(c) for c in ties)
    for c in model.candidates(n_rows, d, budget):
        assert c.dim % c.n_subquantizers == 0 and (1 << c.nbits) <= n_rows
        assert c.dim == d or c.dim <= n_rows


def test_opq_counts_its_rotation_even_without_reduction():
    config = PQConfig(48, 8, 4)
    assert PQLocalizer().planned_bytes(400, 48, config=config, always_project=True) == \
        PQLocalizer().planned_bytes(400, 48, config=config) + 48 * 48 * 4


def test_rule_is_deterministic_and_monotone_in_budget():
    pq = PQLocalizer()
    bits = [pq.choose_config(400, 48, b).code_bits for b in (3_000, 10_000, 30_000, 100_000, 300_000)]
    assert bits == sorted(bits)
    assert pq.choose_config(400, 48, 30_000) == pq.choose_config(400, 48, 30_000)


@pytest.mark.parametrize("budget", [100, 500])
def test_budget_error_names_the_smallest_configuration(budget):
    with pytest.raises(BudgetTooSmallError) as info:
        PQLocalizer().choose_config(400, 48, budget)
    minimum = info.value.minimum
    pq = PQLocalizer()
    everything = pq.candidates(400, 48, 10 ** 9)  # every p: the minimum is that of all configurations
    assert minimum == min(pq.planned_bytes(400, 48, config=c) for c in everything) == 400 + 16 * 4 + 48 * 4
    assert f"{minimum} B" in str(info.value) and "p = 1" in str(info.value)
    assert pq.choose_config(400, 48, minimum) == PQConfig(1, 1, 4)


def test_wide_descriptors_spend_the_budget_beyond_powers_of_two():
    """d = 8192, N = 2000, 256 KB: the d×p projection is most of the bytes; p was a power of two (4), leaving
    44 % of the budget unspent at 32 code bits; every p whose projection fits is now a candidate."""
    pq = PQLocalizer()
    config = pq.choose_config(2000, 8192, 256_000)
    assert config == PQConfig(7, 7, 8) and config.code_bits == 56
    assert 0.95 * 256_000 <= pq.planned_bytes(2000, 8192, config=config) <= 256_000


def test_defaults_without_budget():
    assert PQLocalizer().choose_config(3576, 3780, None) == PQConfig(256, 32, 8)
    assert PQLocalizer().choose_config(3576, 100, None) == PQConfig(100, 25, 8)
    # Fewer rows than 256 centroids: 4-bit codes (k-means needs a point per centroid).
    assert PQLocalizer().choose_config(64, 48, None) == PQConfig(48, 24, 4)
    assert PQLocalizer(pca_dim=16, n_subquantizers=4).choose_config(400, 48, None) == PQConfig(16, 4, 8)


def test_explicit_parameters_are_honoured_and_validated(data):
    X, Q = data
    model = PQLocalizer(n_subquantizers=8, nbits=4, pca_dim=16, n_jobs=1).fit(X)
    assert model.config_ == PQConfig(16, 8, 4)
    assert model.projection_.shape == (48, 16) and model.projection_.dtype == np.float32
    assert model.codebooks_.shape == (8, 16, 2) and model.codes_.shape == (400, 4)
    assert model.storage_breakdown() == {"codes": 1600, "codebooks": 16 * 16 * 4, "projection": 48 * 16 * 4}
    with pytest.raises(InvalidParameterError, match="must divide"):
        PQLocalizer(n_subquantizers=5, pca_dim=16).fit(X)
    with pytest.raises(InvalidParameterError, match="nbits=8 needs at least 256"):
        PQLocalizer(nbits=8).fit(X[:100])
    with pytest.raises(InvalidParameterError, match="pca_dim=64 exceeds"):
        PQLocalizer(pca_dim=64).fit(X)
    with pytest.raises(InvalidParameterError, match="nbits must be None or an integer ≥ 1 and ≤ 8; got 9"):
        PQLocalizer(nbits=9).fit(X)
    # A map of under 16 rows gets the most bits with a row per centroid (3 for 10 rows), not an error.
    tiny = PQLocalizer(n_jobs=1).fit(X[:10])
    assert tiny.config_.nbits == 3 and PQLocalizer(budget="2KB", n_jobs=1).fit(X[:10]).config_.nbits == 3
    assert np.mean(tiny.predict(X[:10]) == np.arange(10)) >= 0.9
    # An explicit configuration that does not fit the budget: the error names its size.
    with pytest.raises(BudgetTooSmallError):
        PQLocalizer(budget=1_000, n_subquantizers=48, nbits=8, pca_dim=48).fit(X)


def test_small_map_falls_back_to_4_bit_codes(data):
    X, Q = data
    model = PQLocalizer(n_jobs=1).fit(X[:64])
    assert model.config_.nbits == 4
    assert np.mean(model.predict(Q[:64]) == np.arange(64)) >= 0.9


def test_pq_search_is_an_exact_scan_of_asymmetric_distances(data):
    X, Q = data
    model = PQLocalizer(n_subquantizers=8, nbits=4, pca_dim=16, n_jobs=1).fit(X)
    # Decode every code with numpy and compare the query (projected, not quantised) with each.
    M, ksub, dsub = model.codebooks_.shape
    packed = model.codes_
    nibbles = np.stack([packed & 0x0F, packed >> 4], axis=2).reshape(len(packed), -1)[:, :M]
    recon = np.concatenate([model.codebooks_[m][nibbles[:, m]] for m in range(M)], axis=1)
    dist = (((model.front_end_.transform(Q) @ model.projection_)[:, None, :] - recon[None]) ** 2).sum(-1)
    ranked = model.rank(Q, 5)
    np.testing.assert_allclose(np.take_along_axis(dist, ranked[:, :1], 1)[:, 0], dist.min(1), rtol=1e-4, atol=1e-4)


def test_no_pca_means_no_projection_stored(data):
    X, _ = data
    model = PQLocalizer(budget="20KB", n_jobs=1).fit(X)
    assert model.config_.dim == 48 and model.projection_ is None
    assert set(model.storage_breakdown()) == {"codes", "codebooks"}


def test_opq_projection_has_orthonormal_columns(data):
    X, Q = data
    model = OPQLocalizer(pq=PQLocalizer(pca_dim=16, n_subquantizers=4, nbits=4), n_iter=5, n_jobs=1).fit(X)
    P = model.projection_
    assert P.shape == (48, 16)
    np.testing.assert_allclose(P.T @ P, np.eye(16), atol=1e-4)
    assert set(model.storage_breakdown()) == {"codes", "codebooks", "projection"}
    with pytest.raises(InvalidParameterError, match="n_iter"):
        OPQLocalizer(n_iter=0).fit(X)


def test_opq_quantises_better_than_pq_at_the_same_configuration(data):
    # OPQ's rotation exists to lower the quantisation error of the same code (Ge et al. 2014).
    X, _ = data
    errors = []
    pq = PQLocalizer(pca_dim=16, n_subquantizers=4, nbits=4, n_jobs=1)
    for model in (pq, OPQLocalizer(pq=pq, n_jobs=1)):
        model.fit(X)
        quantiser = model if isinstance(model, PQLocalizer) else model.pq_
        Y = X @ model.projection_
        errors.append(float(((quantiser._index.sa_decode(quantiser.codes_) - Y) ** 2).sum()))
    assert errors[1] < errors[0]


# -- ITQ -----------------------------------------------------------------------------------------
def test_itq_code_length_rule(data):
    X, _ = data
    itq = ITQLocalizer()
    assert itq.choose_code_bits(400, 48, None) == 48
    assert itq.planned_bytes(400, 48, code_bits=16) == 400 * 2 + (48 * 16 + 48) * 4
    budget = itq.planned_bytes(400, 48, code_bits=24) + 10
    assert itq.choose_code_bits(400, 48, budget) == 24
    with pytest.raises(BudgetTooSmallError) as info:
        itq.choose_code_bits(400, 48, 100)
    assert info.value.minimum == itq.planned_bytes(400, 48, code_bits=8)
    with pytest.raises(InvalidParameterError, match="multiple of 8"):
        ITQLocalizer(code_bits=12).fit(X)
    with pytest.raises(NotEnoughPlacesError):
        ITQLocalizer().fit(X[:, :4])


def test_itq_codes_are_signs_and_search_is_exact_hamming(data):
    X, Q = data
    model = ITQLocalizer(code_bits=32, n_jobs=1).fit(X)
    assert model.codes_.shape == (400, 4) and model.codes_.dtype == np.uint8
    queries = Q
    X, Q = model.front_end_.transform(X), model.front_end_.transform(Q)  # codes of the front end's rows
    bits = np.unpackbits(model.codes_, axis=1).astype(bool)
    np.testing.assert_array_equal(bits, (X - model.mean_) @ model.projection_ > 0)
    # The rotation keeps the PCA directions orthonormal.
    P = model.projection_
    np.testing.assert_allclose(P.T @ P, np.eye(32), atol=1e-4)
    qbits = (Q - model.mean_) @ model.projection_ > 0
    hamming = (qbits[:, None, :] != bits[None]).sum(-1)
    pred = model.predict(queries)
    np.testing.assert_array_equal(hamming[np.arange(len(Q)), pred], hamming.min(1))
    assert np.mean(pred == np.arange(100)) >= 0.9


# -- faiss plumbing ------------------------------------------------------------------------------
def test_quiet_faiss_hides_only_the_clustering_warning(capfd):
    x = np.random.default_rng(0).normal(size=(300, 8)).astype(np.float32)
    # Precondition: faiss does print the warning (300 points for 256 centroids).
    faiss.ProductQuantizer(8, 1, 8).train(x)
    assert "WARNING clustering" in capfd.readouterr().err
    with quiet_faiss():
        faiss.ProductQuantizer(8, 1, 8).train(x)
        os.write(2, b"something else\n")
    err = capfd.readouterr().err
    assert "WARNING clustering" not in err
    assert "something else" in err


def test_fit_prints_nothing(data, capfd):
    X, _ = data
    PQLocalizer(nbits=8, n_jobs=1).fit(X)
    assert capfd.readouterr().err == ""


def test_faiss_threads_restores_the_setting():
    before = faiss.omp_get_max_threads()
    with faiss_threads(1):
        assert faiss.omp_get_max_threads() == 1
    assert faiss.omp_get_max_threads() == before


def test_pq_summary_says_what_the_planner_chose_and_what_the_budget_left(data) -> None:
    X, _ = data
    model = PQLocalizer(budget="16KB").fit(X)
    c = model.config_
    line = model.summary()
    assert line.startswith(f"pq: {c.n_subquantizers} sub-quantisers × {c.nbits} bits ({c.code_size} B a row) on ")
    assert f"{model.nbytes:,d} B of the 16,000 B budget" in line and "\n" not in line
    assert ("PCA projection" in line) == (model.projection_ is not None)
    unbudgeted = PQLocalizer().fit(X)
    assert f"{unbudgeted.nbytes:,d} B (no budget)" in unbudgeted.summary()  # its bytes, nothing to compare with


def test_opq_never_asks_faiss_for_a_rotation_wider_than_the_map_has_rows():
    """faiss' OPQMatrix.train corrupts its heap on fewer rows than dimensions (`btel train` of 200 × 500
    Gardens Point rows with opq at --budget 1e300 ended in SIGSEGV or SIGABRT). p is now ≤ N."""
    from btel.exceptions import InvalidParameterError
    from btel.methods.baselines.opq import OPQLocalizer

    X = np.random.default_rng(0).standard_normal((40, 60)).astype(np.float32)
    big = OPQLocalizer(budget=10**12, n_iter=2)
    config = big._choose_config(big._quantiser(), 40, 60, 10**12, 0)
    assert config.dim <= 40
    assert OPQLocalizer()._choose_config(OPQLocalizer()._quantiser(), 40, 60, None, 0).dim <= 40
    model = OPQLocalizer(budget=10**12, n_iter=2).fit(X)
    assert model.config_.dim <= 40 and model.predict(X[:5]).tolist() == list(range(5))
    with pytest.raises(InvalidParameterError, match="p must be ≤ N = 40"):
        OPQLocalizer(pq=PQLocalizer(pca_dim=50)).fit(X)


@pytest.mark.parametrize("cls", [PQLocalizer, OPQLocalizer], ids=["pq", "opq"])
def test_batch_search_bounds_the_look_up_tables(data, cls, monkeypatch):
    # faiss builds every query's M × 2^nbits distance table at once: a batch is searched in chunks whose
    # tables fit SEARCH_SCRATCH_BYTES, with the answers of one whole batch.
    import btel.methods.baselines._common as common

    X, Q = data
    model = cls(budget=20_000).fit(X)
    whole_scores, whole_places = model.search(Q, k=5)
    per_query = model._search_bytes_per_query()
    assert per_query == (
        (model.pq_ if cls is OPQLocalizer else model).config_.n_subquantizers
        * (1 << (model.pq_ if cls is OPQLocalizer else model).config_.nbits) * 4)
    calls = []
    original = type(model)._search_rows

    def counted(self, Qc, k, scores=True):
        calls.append(Qc.shape[0])
        return original(self, Qc, k, scores)

    monkeypatch.setattr(common, "SEARCH_SCRATCH_BYTES", 7 * per_query)
    monkeypatch.setattr(type(model), "_search_rows", counted)
    scores, places = model.search(Q, k=5)
    assert calls == [7] * (Q.shape[0] // 7) + [Q.shape[0] % 7]
    np.testing.assert_array_equal(places, whole_places)
    np.testing.assert_allclose(scores, whole_scores, rtol=1e-6)
    np.testing.assert_array_equal(model.predict(Q), whole_places[:, 0])


@pytest.mark.parametrize("cls", [PQLocalizer, OPQLocalizer], ids=["pq", "opq"])
def test_codes_too_short_to_tell_the_rows_apart_are_warned_about(cls):
    # 400 rows of d = 512 at 3 KB: the projection takes the budget and leaves codes of < log2 400 bits.
    import warnings

    from btel.exceptions import CollidingCodesWarning

    X = np.random.default_rng(0).normal(size=(400, 512)).astype(np.float32)
    with pytest.warns(CollidingCodesWarning, match=r"at most \d+ distinct codes for 400 map rows"):
        small = cls(budget=3_000).fit(X)
    config = (small.pq_ if cls is OPQLocalizer else small).config_
    assert 2 ** config.code_bits < 400
    with warnings.catch_warnings():
        warnings.simplefilter("error", CollidingCodesWarning)
        large = cls(budget=200_000).fit(X)
    assert 2 ** (large.pq_ if cls is OPQLocalizer else large).config_.code_bits >= 400
