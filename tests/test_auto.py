"""auto: the map-only rule (btel.methods.auto.rule) and its statistics, in the model file and summary."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import btel
from btel.datasets import synthetic_route
from btel.methods.auto import (ORDER_BITS_FACTOR, ORDER_CONTINUITY, ROUTE_CONTINUITY, ROUTE_SHARE, choose_method, collision_bits,
                               route_continuity, route_share)
from btel.exceptions import (BudgetTooSmallError, InvalidDescriptorsError, InvalidParameterError, ModelFileError,
                             NotEnoughPlacesError)
from btel.methods import make_method


@pytest.fixture(scope="module")
def smooth_route():
    """A route whose consecutive rows look alike (a random walk), and the same rows permuted."""
    rng = np.random.default_rng(0)
    X = np.cumsum(rng.normal(size=(300, 32)), axis=0).astype(np.float32) + 20
    Q = X + 0.3 * rng.normal(size=X.shape).astype(np.float32)
    return X, Q


def test_route_share_separates_a_route_from_its_permutation(smooth_route) -> None:
    X, _ = smooth_route
    perm = np.random.default_rng(1).permutation(X.shape[0])
    assert route_share(X) > 0.9 and route_share(X[perm]) < 0.1
    # Place labels count, not row numbers: two traverses of one route are still a route.
    assert route_share(np.concatenate([X, X + 0.01]), np.concatenate([np.arange(300)] * 2)) > 0.9


def snippets(n_rows: int, length: int, seed: int = 0) -> np.ndarray:
    """Row order of a route cut into snippets of ``length`` consecutive rows, the snippets shuffled."""
    usable = n_rows // length * length
    parts = np.arange(usable).reshape(-1, length)
    return np.concatenate(parts[np.random.default_rng(seed).permutation(len(parts))])


def test_route_continuity_is_high_along_a_route_and_half_for_shuffled_snippets(smooth_route) -> None:
    X, _ = smooth_route
    assert route_continuity(X) > 0.9
    assert abs(route_continuity(X[np.random.default_rng(1).permutation(300)]) - 0.5) < 0.05
    three = X[snippets(300, 3)]
    # Snippets of three frames pass the route share (the nearest other row is in the snippet) but not the continuity.
    assert route_share(three) >= ROUTE_SHARE and route_continuity(three) < ROUTE_CONTINUITY
    assert choose_method(three, None, 300, 4_000)[0]["method"] == "lsh"
    route = choose_method(X, None, 300, 4_000)[0]
    assert route["method"] == "btel-codes" and route["route_continuity"] >= ROUTE_CONTINUITY
    # Place labels count: two traverses of the route, stacked, are still a route.
    both = np.concatenate([X, X + 0.05])
    labels = np.concatenate([np.arange(300)] * 2)
    assert route_continuity(both, labels) > 0.9
    assert route_continuity(X[:3]) == 0.5   # no rows 3 places apart: no evidence of order


def test_the_rule_uses_no_queries_and_records_why(smooth_route) -> None:
    X, _ = smooth_route
    route = choose_method(X, None, 300, 4_000)
    assert route[0]["method"] == "btel-codes" and route[0]["route_share"] >= ROUTE_SHARE
    perm = np.random.default_rng(1).permutation(300)
    independent = choose_method(X[perm], None, 300, 4_000)
    assert independent[0]["method"] == "lsh" and "independent places" in independent[0]["reason"]
    assert choose_method(X[perm], None, 300, None)[0]["method"] == "bruteforce"


def test_an_ordered_map_with_fewer_bits_than_the_birthday_bound_gets_output_codes() -> None:
    from btel.datasets import synthetic_route

    # A route whose consecutive places do not look alike most of the time (route share 0.12).
    X = synthetic_route(2048, 256, condition_shift=1.0, seed=7).map
    assert 0.1 <= route_share(X) < ROUTE_SHARE and route_continuity(X) >= ORDER_CONTINUITY
    assert collision_bits(2048) == pytest.approx(22.0)
    few = choose_method(X, None, 2048, 4096)        # 16 bits per place < 22
    assert few[0]["method"] == "btel-codes" and "2·log2 N" in few[0]["reason"]
    assert [c["method"] for c in few[1:]] == ["lsh"]
    assert choose_method(X, None, 2048, 16384)[0]["method"] == "lsh"   # 64 bits per place
    # The same rows permuted are not ordered: few bits still go to LSH.
    perm = np.random.default_rng(1).permutation(2048)
    assert route_continuity(X[perm]) < ORDER_CONTINUITY
    assert choose_method(X[perm], None, 2048, 4096)[0]["method"] == "lsh"


def test_the_rule_whitens_independent_places_from_d_bits_and_centres_a_cone_short_of_d_bits() -> None:
    """Independent places: plain LSH while P < d, shrinkage-whitened from P ≥ d; a cone: centred while P < d;
    an ordered map (a route of many bits) is never whitened by the rule."""
    rng = np.random.default_rng(3)
    X = rng.normal(size=(200, 500)).astype(np.float32)
    short = choose_method(X, None, 200, 8_000)[0]                    # P = 320 < d = 500
    assert short["method"] == "lsh" and short["params"] == {"center": False}, short
    for budget in (64_000, 300_000):                                  # P ≥ d
        first = choose_method(X, None, 200, budget)[0]
        assert first["params"] == {"whiten": "shrink", "center": False} and "whitened" in first["reason"]
    exact = choose_method(X, None, 200, None)[0]
    assert exact["method"] == "bruteforce" and exact["params"] == {"whiten": "shrink"}
    cone = X + 2.0 * np.abs(X).max() * np.ones(500, dtype=np.float32)
    centred = choose_method(cone, None, 200, 8_000)[0]
    assert centred["params"] == {"center": True} and "centred rows" in centred["reason"]
    route = synthetic_route(2048, 256, condition_shift=1.0, seed=7).map        # ordered: continuity ≥ 0.6
    many = choose_method(route, None, 2048, 256_000)[0]                        # P = 1000 ≥ d = 256
    assert many["method"] == "lsh" and "whiten" not in many["params"]
    # A user's whiten is given to every candidate.
    assert all(c["params"].get("whiten") == 64 for c in choose_method(X, None, 200, 64_000, 64))


def test_exact_search_when_the_float32_map_fits_and_lsh_below_it() -> None:
    X = np.random.default_rng(4).normal(size=(400, 4096)).astype(np.float32)
    assert [c["method"] for c in choose_method(X, None, 400, 400 * 256)] == ["lsh", "btel-codes"]
    assert choose_method(X, None, 400, 400 * 4096 * 4)[0]["method"] == "bruteforce"
    assert choose_method(X, None, 400, 400 * 4096 * 4 - 1)[0]["method"] == "lsh"
    assert choose_method(X, None, 400, None)[0]["method"] == "bruteforce"


def test_an_ordered_cone_that_cannot_afford_lsh_mean_gets_output_codes() -> None:
    """Ordered map in a cone, LSH's mean over 1/8 of the budget: its uncentred bits carry little, so codes;
    with the mean affordable (centred bits count whole), or no cone: LSH."""
    from btel.methods.baselines.lsh import cone_ratio

    route = synthetic_route(600, 512, condition_shift=1.0, seed=2)
    offset = np.full(512, 3 * np.linalg.norm(route.map, axis=1).mean() / np.sqrt(512), dtype=np.float32)
    cone = route.map + offset
    assert cone_ratio(btel.core.frontend.normalize_rows(cone)) >= 0.5 > cone_ratio(btel.core.frontend.normalize_rows(route.map))
    assert route_continuity(cone) >= ORDER_CONTINUITY and route_continuity(route.map) >= ORDER_CONTINUITY
    budget = 6_000  # 80 bits per row, above 2·log2 N; LSH's 1 KB mean is over 1/8 of it
    first = choose_method(cone, None, 600, budget)[0]
    assert first["method"] == "btel-codes" and "cone ratio" in first["reason"]
    assert first["lsh_effective_bits"] < ORDER_BITS_FACTOR * collision_bits(600) < 80
    assert choose_method(route.map, None, 600, budget)[0]["method"] == "lsh"
    assert choose_method(cone, None, 600, 16_000)[0]["method"] == "lsh"   # the mean fits: centred LSH


def test_an_ordered_cone_with_many_bits_per_place_keeps_lsh() -> None:
    """The shape of a small NetVLAD set (N = 210, d = 500) at 4 KB: 152 bits per row, uncentred on a cone of
    ratio ≈ 0.73 still carry ≈ 106 effective bits, far above 2 × 2·log2 N = 31 (bench_cone_route: LSH
    0.905 / 0.440 against codes 0.660 / 0.214 on the easy / hard synthetic route of that shape)."""
    from btel.methods.baselines.lsh import cone_ratio

    route = synthetic_route(210, 500, condition_shift=2.5, noise=0.6, seed=31)
    direction = np.random.default_rng(9).normal(size=500).astype(np.float32)
    direction *= np.linalg.norm(route.map, axis=1).mean() / np.linalg.norm(direction)
    X = route.map + direction
    assert 0.5 <= cone_ratio(btel.core.frontend.normalize_rows(X)) < 0.8
    assert route_share(X) < ROUTE_SHARE and route_continuity(X) >= ORDER_CONTINUITY
    first = choose_method(X, None, 210, 4_000)[0]
    assert first["method"] == "lsh" and first["lsh_effective_bits"] > ORDER_BITS_FACTOR * collision_bits(210)


def test_an_ordered_cone_in_snippets_of_three_keeps_lsh() -> None:
    """Pairs and triples of alike rows next to each other (route share ≥ 0.1, like the issue's NetVLAD sets of
    independent places at 0.14–0.40) are no order beyond the nearest frames: continuity ≈ 0.5 < ORDER_CONTINUITY,
    so LSH, which beats the periodic codes there at recall@0 (bench_ordered_snippets); the uncut route keeps them."""
    from btel.methods.baselines.lsh import cone_ratio

    route = synthetic_route(600, 500, condition_shift=1.0, noise=0.2, seed=31)
    direction = np.random.default_rng(9).normal(size=500).astype(np.float32)
    direction *= 1.5 * np.linalg.norm(route.map, axis=1).mean() / np.linalg.norm(direction)
    order = np.concatenate(np.arange(600).reshape(-1, 3)[np.random.default_rng(3).permutation(200)])
    X, Q = (route.map + direction)[order], (route.queries + direction)[order]
    assert cone_ratio(btel.core.frontend.normalize_rows(X)) > 0.8 and 0.1 <= route_share(X) < ROUTE_SHARE
    assert route_continuity(X) < ORDER_CONTINUITY <= route_continuity(route.map + direction)
    first = choose_method(X, None, 600, 4_000)[0]
    assert first["method"] == "lsh" and f"continuity {first['route_continuity']:.2f} < {ORDER_CONTINUITY}" in first["reason"]
    assert choose_method(route.map + direction, None, 600, 4_000)[0]["method"] == "btel-codes"
    exact = {name: np.mean([(make_method(name, budget=4_000, random_state=seed).fit(X).predict(Q)
                             == np.arange(600)).mean() for seed in range(2)]) for name in ("lsh", "btel-codes")}
    assert exact["lsh"] > 2 * exact["btel-codes"]


@pytest.mark.parametrize("budget", [2_000, 20_000, None])
def test_auto_fits_within_budget_round_trips_and_says_what_it_chose(smooth_route, budget, tmp_path) -> None:
    X, Q = smooth_route
    model = make_method("auto", **({"budget": budget} if budget else {})).fit(X)
    if budget:
        assert model.nbytes <= budget
    assert model.choice_["method"] in model.summary() and "route share" in model.summary()
    again = btel.load(model.save(tmp_path / "m.npz"))
    assert again.choice_["method"] == model.choice_["method"] and again.summary() == model.summary()
    np.testing.assert_array_equal(again.search(Q, 5)[1], model.search(Q, 5)[1])
    assert again.nbytes == model.nbytes


def test_the_summary_defines_every_figure_its_reason_uses(smooth_route) -> None:
    from btel.methods.auto.rule import reason_terms

    X, _ = smooth_route
    model = make_method("auto", budget=2_000).fit(X)
    reason, legend = model.choice_["reason"], model.summary().splitlines()[1]
    for figure in ("route share", "continuity", "P = ", "cone ratio"):
        assert (figure in reason) == (f"{figure.rstrip(' =')} = " in legend), figure
    assert legend.endswith("(the rule: docs/decisions/auto-rule.md).")
    assert reason_terms("route (route share 0.9 ≥ 0.5)").count("=") == 1
    assert reason_terms("fallback: plain LSH") == ""


def test_a_budget_no_candidate_fits_names_the_minimum(smooth_route) -> None:
    with pytest.raises(BudgetTooSmallError, match="auto") as info:
        make_method("auto", budget=10).fit(smooth_route[0])
    assert info.value.minimum > 10


def test_an_edited_choice_is_a_model_file_error(smooth_route, tmp_path) -> None:
    import json
    import zipfile

    model = make_method("auto", budget=4_000).fit(smooth_route[0])
    path = model.save(tmp_path / "m.npz")
    with np.load(path) as z:
        arrays = dict(z)
    header = json.loads(bytes(arrays["__btel_header__"]).decode())
    header["state"]["choice"]["method"] = "auto"
    arrays["__btel_header__"] = np.frombuffer(json.dumps(header).encode(), dtype=np.uint8)
    bad = tmp_path / "bad.npz"
    np.savez(bad, **arrays)
    assert zipfile.is_zipfile(bad)
    with pytest.raises(ModelFileError, match="registered method"):
        btel.load(bad)


def test_cli_train_defaults_to_auto_and_prints_its_choice(smooth_route, tmp_path) -> None:
    from click.testing import CliRunner

    from btel.cli import main

    np.save(tmp_path / "db.npy", smooth_route[0])
    result = CliRunner().invoke(main, ["train", str(tmp_path / "db.npy"), "-o", str(tmp_path / "m.npz"),
                                       "--budget", "4KB"])
    assert result.exit_code == 0, result.output
    assert "auto chose btel-codes" in result.output and "route share" in result.output
    info = CliRunner().invoke(main, ["info", str(tmp_path / "m.npz")])
    assert info.exit_code == 0 and "auto chose btel-codes" in info.output


@pytest.mark.realdata
def test_gardens_point_is_a_route_and_permuted_it_is_not(gardenspoint_netvlad) -> None:
    X, _ = gardenspoint_netvlad
    assert route_share(X) >= ROUTE_SHARE
    assert route_share(X[np.random.default_rng(0).permutation(X.shape[0])]) < ROUTE_SHARE


def test_gardens_point_codes_beat_lsh_mapped_by_day(gardenspoint_netvlad) -> None:
    """The route rule's evidence: mapped by day, auto's output codes beat LSH at 32 KB (the issue's target)."""
    X, Q = gardenspoint_netvlad
    truth = np.arange(X.shape[0])
    auto = make_method("auto", budget="32KB").fit(X)
    lsh = make_method("lsh", budget="32KB").fit(X)
    assert auto.choice_["method"] == "btel-codes"
    near = lambda model: float(np.mean(np.abs(model.predict(Q) - truth) <= 2))
    assert near(auto) >= 0.60 and near(auto) > near(lsh) + 0.1   # measured 0.615 vs 0.44 (seed 0)


@pytest.mark.xfail(strict=True, reason="known miss (README 'Which method'): mapped at night, Gardens Point is still a "
                                       "route by its map, auto gives it output codes, and LSH beats them "
                                       "(recall@2 0.520 vs 0.625 at 32 KB, mean of three seeds)")
def test_gardens_point_mapped_at_night_auto_keeps_up_with_lsh(gardenspoint_netvlad) -> None:
    day, night = gardenspoint_netvlad
    truth = np.arange(day.shape[0])
    auto = make_method("auto", budget="32KB").fit(night)
    lsh = make_method("lsh", budget="32KB").fit(night)
    near = lambda model: float(np.mean(np.abs(model.predict(day) - truth) <= 2))
    assert near(auto) >= 0.95 * near(lsh)


def test_gardens_point_snippets_are_not_a_route(gardenspoint_netvlad) -> None:
    """Gardens Point cut into snippets of 3 frames in random order: route share 0.62 but continuity 0.52, so
    LSH, not the periodic codes that lost there (bench_route_snippets: 0.059 / 0.089 vs LSH 0.130 / 0.140 at 4 /
    16 KB); the route itself keeps its codes."""
    X, _ = gardenspoint_netvlad
    cut = X[snippets(200, 3, seed=3)]
    assert route_share(cut) >= ROUTE_SHARE and route_continuity(cut) < ROUTE_CONTINUITY <= route_continuity(X)
    assert make_method("auto", budget="16KB").fit(cut).choice_["method"] == "lsh"
    assert make_method("btel-codes", code="auto", budget="16KB").fit(cut).code_ == "random"


@settings(max_examples=25, deadline=None)
@given(n_rows=st.integers(2, 60), dim=st.integers(1, 8), seed=st.integers(0, 2**16), repeats=st.integers(1, 3))
def test_route_continuity_is_a_rank_in_zero_one_for_any_map(n_rows: int, dim: int, seed: int, repeats: int) -> None:
    """Any map, with or without repeated place labels (duplicate rows included): a mean rank in [0, 1]."""
    rng = np.random.default_rng(seed)
    X = rng.normal(size=(n_rows, dim)).astype(np.float32)
    X[rng.integers(0, n_rows)] = X[0]
    labels = np.repeat(np.arange(-(-n_rows // repeats)), repeats)[:n_rows]
    if labels.max() < 1:  # one place: no map (NotEnoughPlacesError, as a fit)
        with pytest.raises(NotEnoughPlacesError):
            route_continuity(X, labels)
        return
    value = route_continuity(X, labels)
    assert 0.0 <= value <= 1.0


@pytest.mark.parametrize("bad, error", [
    (np.zeros(5, dtype=np.float32), InvalidDescriptorsError),               # 1-D
    (np.full((5, 3), np.nan, dtype=np.float32), InvalidDescriptorsError),   # NaN
    (np.zeros((0, 4), dtype=np.float32), InvalidDescriptorsError),          # empty
    (np.ones((1, 4), dtype=np.float32), NotEnoughPlacesError),              # N = 1
    (np.array([["a", "b"], ["c", "d"]]), InvalidDescriptorsError),          # not numbers
])
def test_map_statistics_refuse_bad_maps_with_the_fit_errors(bad, error) -> None:
    from btel.methods.auto import index_order, map_cone_ratio

    for statistic in (route_share, route_continuity, index_order):
        with pytest.raises(error):
            statistic(bad)
    if error is InvalidDescriptorsError:
        with pytest.raises(error):
            map_cone_ratio(bad)
    with pytest.raises(InvalidParameterError, match="places"):
        route_share(np.ones((4, 3), dtype=np.float32), [0, 1, 1, 5])


@settings(max_examples=25, deadline=None)
@given(n_rows=st.integers(2, 80), dim=st.integers(3, 8), seed=st.integers(0, 2**16))
def test_route_share_is_the_share_of_nearest_other_rows_within_the_window(n_rows: int, dim: int, seed: int) -> None:
    """The blockwise search equals a full cosine matrix: every probe's nearest row other than itself (d ≥ 3:
    on a line every row ties with half the map)."""
    rng = np.random.default_rng(seed)
    X = rng.normal(size=(n_rows, dim)).astype(np.float32)
    Z = btel.core.frontend.normalize_rows(X)
    S = Z @ Z.T
    np.fill_diagonal(S, -np.inf)
    expected = 0.0 if n_rows < 2 else float(np.mean(np.abs(np.argmax(S, axis=1) - np.arange(n_rows)) <= 2))
    assert route_share(X) == pytest.approx(expected)


def test_map_statistics_read_a_memory_mapped_map_in_blocks(smooth_route, tmp_path) -> None:
    """Same values from a memory-mapped map as from memory (no whole-map copy is needed)."""
    from btel.methods.auto import map_cone_ratio
    from btel.methods.baselines.lsh import cone_ratio

    X, _ = smooth_route
    path = tmp_path / "map.npy"
    np.save(path, X)
    mapped = np.load(path, mmap_mode="r")
    assert route_share(mapped) == route_share(X) and route_continuity(mapped) == route_continuity(X)
    assert map_cone_ratio(mapped) == pytest.approx(cone_ratio(btel.core.frontend.normalize_rows(X)), rel=1e-6)


def test_index_order_tells_a_route_an_ordered_map_and_independent_places(smooth_route) -> None:
    """A smooth walk is a route; a synthetic route of sparse frames (share ≈ 0.1–0.4, continuity ≈ 0.97) is
    ordered; the walk in snippets of three or permuted is independent places."""
    from btel.methods.auto import index_order

    X, _ = smooth_route
    assert index_order(X).kind == "route"
    sparse = synthetic_route(600, 64, seed=3).map
    order = index_order(sparse)
    assert order.kind == "ordered" and order.share < ROUTE_SHARE
    assert order.continuity >= ORDER_CONTINUITY and f"{order.continuity:.2f}" in order.why
    three = index_order(X[snippets(300, 3)])
    assert three.kind == "independent" and three.continuity < ORDER_CONTINUITY and "no order" in three.why
    permuted = index_order(X[np.random.default_rng(1).permutation(300)])
    assert permuted.kind == "independent" and abs(permuted.continuity - 0.5) < 0.05
    # A route of noisy frames: the nearest row is seldom the next frame (share < 0.1), but the order holds.
    noisy = index_order(synthetic_route(1500, 48, condition_shift=0.5, seed=3).map)
    assert noisy.kind == "ordered" and noisy.share < 0.1 and noisy.continuity > 0.9
    # btel-codes code='auto' reads the same test: periodic codes on the ordered map, random on the snippets.
    assert make_method("btel-codes", code="auto", budget="8KB", random_state=0).fit(sparse).code_ == "periodic"
    assert make_method("btel-codes", code="auto", budget="8KB", random_state=0).fit(X[snippets(300, 3)]).code_ == "random"


def test_route_share_of_a_large_map_searches_spans_of_consecutive_places() -> None:
    """Past ``search_rows`` the share searches evenly spaced spans (bounded cost): a route stays a route, its
    permutation independent places (chance is 4 / span: 0.02 for the spans of 200 rows here, 0.0005 at the
    default 8192), and two stacked traverses (place labels) still a route."""
    rng = np.random.default_rng(5)
    walk = np.cumsum(rng.normal(size=(3000, 16)), axis=0).astype(np.float32)
    assert route_share(walk, search_rows=1600) > 0.9 and route_share(walk, search_rows=1600) == pytest.approx(
        route_share(walk), abs=0.05)
    assert route_share(walk[rng.permutation(3000)], search_rows=1600) < 0.05
    both = np.concatenate([walk, walk + 0.01 * rng.normal(size=walk.shape).astype(np.float32)])
    assert route_share(both, np.concatenate([np.arange(3000)] * 2), search_rows=1600) > 0.9


def test_a_second_traverse_of_the_same_places_does_not_make_a_map_a_route() -> None:
    # With several traverses, a row's nearest row is its own place seen again: the route statistics
    # compare it with other places only, so the rule reads the same map with one traverse or two.
    from btel.datasets import synthetic_route
    from btel.methods.auto.statistics import route_share

    r = synthetic_route(n_places=600, dim=64, seed=0, n_traverses=2)
    places = np.r_[np.arange(600), np.arange(600)]
    both = np.vstack(r.traverses)
    assert abs(route_share(both, places) - route_share(r.map)) < 0.05
    one = make_method("auto", budget="16KB").fit(r.map).choice_
    two = make_method("auto", budget="16KB").fit(both, places).choice_
    assert (two["method"], two["params"]) == (one["method"], one["params"])


def test_a_wide_or_long_map_is_probed_by_fewer_rows_and_reads_the_same() -> None:
    """`probe_rows` keeps probes × rows searched × d within STAT_PRODUCTS (never below 500 probes, never
    above 2,000); a route, its permutation and a sparse route read the same kind with 500 probes as with
    2,000 (the statistics are means over probes)."""
    from btel.methods.auto.statistics import MIN_STAT_ROWS, STAT_PRODUCTS, STAT_ROWS, index_order, probe_rows

    assert probe_rows(200, 500) == STAT_ROWS and probe_rows(3576, 3780) == STAT_PRODUCTS // (3576 * 3780)
    assert probe_rows(10_000, 16_384) == MIN_STAT_ROWS == probe_rows(10**6, 49_152)
    sizes = [probe_rows(n, d) for n, d in ((2000, 256), (2000, 8192), (10_000, 8192), (10_000, 16_384))]
    assert sizes == sorted(sizes, reverse=True)
    rng = np.random.default_rng(2)
    walk = np.cumsum(rng.normal(size=(3000, 16)), axis=0).astype(np.float32)
    for X in (walk, walk[rng.permutation(3000)], synthetic_route(3000, 64, seed=3).map):
        full, few = index_order(X, probes=STAT_ROWS), index_order(X, probes=MIN_STAT_ROWS)
        assert few.kind == full.kind
        assert abs(few.share - full.share) < 0.05 and abs(few.continuity - full.continuity) < 0.05
    for bad in (0, -3, 2.5, True):
        with pytest.raises(InvalidParameterError, match="probes must be a whole number"):
            index_order(walk, probes=bad)


@pytest.mark.parametrize("n_rows", [2, 3])
def test_index_order_of_too_few_places_says_so(n_rows: int) -> None:
    """Two or three places hold no pair 3–8 places apart: the reason says there are too few places to
    read an order, rather than quoting a route share of 1.00 beside 'independent places'."""
    from btel.methods.auto import index_order

    X = np.random.default_rng(0).standard_normal((n_rows, 16)).astype(np.float32)
    order = index_order(X)
    assert order.kind == "independent"
    assert order.why.startswith(f"{n_rows} places: too few to read an order") and "route share" not in order.why
    assert "too few to read an order" in make_method("auto", budget="4KB").fit(X).choice_["reason"]


def test_an_ordered_map_of_many_places_per_dimension_gets_codes_only_below_the_bound() -> None:
    """Past CODES_PLACES_PER_DIMENSION places per dimension the codes' linear classifiers cannot learn the
    short-period columns: step 2 then gives them the map only below the birthday bound itself
    (benchmarks/studies/auto_rule_codes_capacity.py). The same bits per row on 2,000 places of d = 64 (31 per
    dimension) keep the codes; on 2,100 (33 per dimension) LSH, which is far ahead there."""
    from btel.methods.auto import CODES_PLACES_PER_DIMENSION

    for n, expected in ((2000, "btel-codes"), (2100, "lsh")):
        route = synthetic_route(n, 64, seed=5)
        budget = int(n * 1.5 * collision_bits(n) / 8)  # LSH between 1 and 2 × the bound
        first = choose_method(route.map, None, n, budget)[0]
        assert collision_bits(n) < first["lsh_effective_bits"] < ORDER_BITS_FACTOR * collision_bits(n)
        assert first["method"] == expected, first["reason"]
        assert (n > CODES_PLACES_PER_DIMENSION * 64) == (expected == "lsh")
    # Whitened to 32 dimensions by the user, the codes' classifiers see 32 features: 2,000 places are too many.
    route2000 = synthetic_route(2000, 64, seed=5)
    whitened = choose_method(route2000.map, None, 2000, int(2000 * 1.5 * collision_bits(2000) / 8), whiten=32)[0]
    assert whitened["method"] == "lsh", whitened["reason"]
    below = choose_method(route.map, None, 2100, int(2100 * 0.8 * collision_bits(2100) / 8))[0]
    assert below["method"] == "btel-codes" and "the bound itself" in below["reason"]
    # On a map of 125 places per dimension the codes locate a query only coarsely.
    route = synthetic_route(4000, 32, seed=5)
    budget, truth = int(4000 * 1.5 * collision_bits(4000) / 8), np.arange(0, 4000, 8)
    chosen = btel.make_method("auto", budget=budget).fit(route.map)
    recall = {name: np.mean(np.abs(btel.make_method(name, budget=budget, random_state=0).fit(route.map)
                                   .predict(route.queries[truth]) - truth) <= 2) for name in ("lsh", "btel-codes")}
    assert chosen.choice_["method"] == "lsh" and recall["lsh"] > recall["btel-codes"] + 0.2, recall
