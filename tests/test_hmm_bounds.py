"""The HMM and the soft scores stay within what a model's N promises (hostile round 3): a speed far
beyond the route, and a tiny model file claiming millions of places."""

from __future__ import annotations

import time
import tracemalloc

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from btel.core.limits import BYTES_PER_PLACE
from btel.exceptions import ResourceLimitError
from btel.methods.btel.compressed import code_scores, code_signs
from btel.methods.btel.encoding import bit_codes, decode_soft, index_scores, n_bits_for
from btel.sequence.hmm import HMMDecoder, transition_kernel


@settings(max_examples=60, deadline=None)
@given(st.integers(2, 3000), st.integers(1, 4), st.integers(0, 2**31 - 1))
def test_index_scores_equal_the_product_with_every_sign_vector(n: int, queries: int, seed: int) -> None:
    """Built by doubling in O(N), equal to margins @ (2·bits − 1).T, which costs an (N, b) matrix."""
    m = np.random.default_rng(seed).standard_normal((queries, n_bits_for(n)))
    expected = m @ bit_codes(n).astype(np.float64).T
    np.testing.assert_allclose(index_scores(m, n), expected, rtol=0, atol=1e-12)
    assert (decode_soft(m, n) == np.argmax(expected, axis=1)).all()


@pytest.mark.parametrize("n, copies", [(2, 1), (5, 2), (1000, 3), (70_000, 2)])
def test_code_scores_made_block_by_block_equal_the_whole_product(n: int, copies: int) -> None:
    signs = code_signs(n, copies).astype(np.float64)
    m = np.random.default_rng(n).standard_normal((3, signs.shape[1]))
    np.testing.assert_allclose(code_scores(m, n, copies), m @ signs.T, rtol=0, atol=1e-10)


@pytest.mark.parametrize("backward", [0.0, 0.2])
@pytest.mark.parametrize("mode", ["forward", "viterbi"])
def test_offsets_beyond_the_route_are_left_out_with_the_same_answers(backward: float, mode: str) -> None:
    """vmax = 10⁹ built 10⁹ offsets (24 GB, killed); offsets ≥ N land nowhere, so leaving them out
    changes no answer, and the others keep their probabilities."""
    n = 40
    rng = np.random.default_rng(1)
    scores = rng.standard_normal((25, n))
    full_offsets, full_weights = transition_kernel(3, 90, backward)  # the kernel without N: every offset
    clipped = HMMDecoder(n, vmin=3, vmax=90, backward=backward, mode=mode)
    reference = HMMDecoder(n, vmin=3, vmax=90, backward=backward, mode=mode)
    reference.offsets, reference.weights = full_offsets, full_weights
    reference._log_weights = np.log((1 - reference.teleport) * full_weights + reference.teleport / n)
    assert clipped.offsets.size < full_offsets.size and np.abs(clipped.offsets).max() == n - 1
    assert [clipped.update(s) for s in scores] == [reference.update(s) for s in scores]
    start = time.perf_counter()
    huge = HMMDecoder(n, vmax=10**9, backward=backward, mode=mode)
    assert huge.offsets.size <= 2 * n and time.perf_counter() - start < 5
    assert isinstance(huge.update(scores[0]), int)


def test_an_hmm_step_stays_within_the_bytes_a_place_promises() -> None:
    """BYTES_PER_PLACE is what a model's N is checked against at load: an HMM step at N = 2²⁰ stays
    under it (it took 56 bytes a place and a float64 (N, b) sign matrix before)."""
    n = 1 << 20
    decoder = HMMDecoder(n, vmax=3, backward=0.1)
    scores = np.random.default_rng(0).standard_normal(n)
    decoder.update(scores)
    tracemalloc.start()
    decoder.update(scores)
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert peak <= (BYTES_PER_PLACE - 8) * n  # the scores (8 B a place) were made before


def test_a_decoder_over_more_places_than_the_limit_allows_is_refused(monkeypatch) -> None:
    monkeypatch.setenv("BTEL_MEMORY_LIMIT", "64M")
    with pytest.raises(ResourceLimitError, match="the HMM decoder with N = 2000000 places"):
        HMMDecoder(2_000_000)
