"""The paper's sequence filter (SPEC §6) on hand-made sequences, streaming and batch."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from btel import SequenceFilter, filter_sequence
from btel.exceptions import InvalidParameterError

# Hand-made sequences; expected outputs worked out by hand in the comments (a = window,
# history = last 2a outputs, m = floor(median), correction when |i − m| > a + 1).
CASES = [
    # a = 2: history [10..13], m = 11, 90 → 11 + 3 = 14; then m = floor(12.5) = 12 and |15 − 12| = 3: kept.
    (2, "forward", "raw", [10, 11, 12, 13, 90, 15], [10, 11, 12, 13, 14, 15]),
    (2, "forward", "filtered", [10, 11, 12, 13, 90, 15], [10, 11, 12, 13, 14, 15]),
    # a = 1 (history 2, reach 2).
    # raw:       40: m=5 → 7 | 41: hist [6,40] m=23 → 25 | 42: hist [40,41] m=40 → kept | 9: m=41 → 43.
    (1, "forward", "raw", [5, 6, 40, 41, 42, 9], [5, 6, 7, 25, 42, 43]),
    # filtered:  40: m=5 → 7 | 41: hist [6,7] m=6 → 8 | 42: hist [7,8] m=7 → 9 | 9: hist [8,9] m=8 → kept.
    (1, "forward", "filtered", [5, 6, 40, 41, 42, 9], [5, 6, 7, 8, 9, 9]),
    # symmetric raw: 40 → clip to [3,7] = 7 | 41: m=23 → 25 | 42 kept | 9: m=41 → clip to [39,43] = 39.
    (1, "symmetric", "raw", [5, 6, 40, 41, 42, 9], [5, 6, 7, 25, 42, 39]),
    # symmetric filtered: 40 → 7 | 41: hist [6,7] m=6 → 8 | 42: hist [7,8] m=7 → 9 | 9: hist [8,9] m=8 → kept.
    (1, "symmetric", "filtered", [5, 6, 40, 41, 42, 9], [5, 6, 7, 8, 9, 9]),
    # Backwards jump: forward mode sends it ahead of the median, symmetric clamps it behind.
    (2, "forward", "raw", [20, 21, 22, 23, 2], [20, 21, 22, 23, 24]),
    (2, "symmetric", "raw", [20, 21, 22, 23, 2], [20, 21, 22, 23, 18]),
    # Even history: m = floor((3 + 6) / 2) = 4, so 7 is 3 > a + 1 = 2 away → 4 + 2 = 6.
    (1, "forward", "raw", [3, 6, 7], [3, 6, 6]),
    # Exactly a + 1 away is not corrected.
    (2, "forward", "raw", [10, 10, 10, 10, 13, 7], [10, 10, 10, 10, 13, 7]),
]


@pytest.mark.parametrize(("window", "mode", "history", "raw", "expected"), CASES)
def test_hand_made_sequences(window, mode, history, raw, expected) -> None:
    out = filter_sequence(raw, window, mode=mode, history=history)
    assert out.dtype == np.int64
    np.testing.assert_array_equal(out, expected)


@pytest.mark.parametrize("mode", ["forward", "symmetric"])
@pytest.mark.parametrize("history", ["raw", "filtered"])
def test_no_correction_before_the_history_holds_2a_outputs(mode: str, history: str) -> None:
    raw = [0, 100, 0, 100, 0, 100, 0]
    out = filter_sequence(raw, 3, mode=mode, history=history)
    np.testing.assert_array_equal(out[:6], raw[:6])
    # Seventh: history [0, 100, 0, 100, 0, 100], m = 50, |0 − 50| > 4.
    assert out[6] == (54 if mode == "forward" else 46)


@pytest.mark.parametrize(("n_places", "expected"), [(None, 100), (100, 99), (1000, 100)])
def test_forward_correction_is_clipped_to_the_last_place(n_places, expected) -> None:
    # m = floor(97.5) = 97 → 97 + 3 = 100, past the last place 99 when N = 100.
    out = filter_sequence([96, 97, 98, 99, 10], 2, n_places=n_places)
    assert out[-1] == expected


def test_streaming_filter_and_reset() -> None:
    f = SequenceFilter(window=2)
    assert [f.update(i) for i in [10, 11, 12, 13, 90]] == [10, 11, 12, 13, 14]
    f.reset()
    # After a reset the history is empty again: nothing is corrected for 2a outputs.
    assert [f.update(i) for i in [500, 10, 11, 12]] == [500, 10, 11, 12]


def reference_filter(raw: list[int], a: int, mode: str, history: str, n_places: int | None) -> list[int]:
    """The rule of SPEC §6 written out plainly, for comparison."""
    past: list[int] = []
    out = []
    for i in raw:
        o = i
        if len(past) == 2 * a:
            mid = sorted(past)
            m = (mid[a - 1] + mid[a]) // 2  # even-sized history: floor of the mean of the middle two
            if abs(i - m) > a + 1:
                o = m + a + 1 if mode == "forward" else min(max(i, m - a - 1), m + a + 1)
                if n_places is not None:
                    o = min(max(o, 0), n_places - 1)
        past.append(i if history == "raw" else o)
        past = past[-2 * a :]
        out.append(o)
    return out


@settings(max_examples=200, deadline=None)
@given(
    raw=st.lists(st.integers(0, 199), max_size=60),
    window=st.integers(1, 6),
    mode=st.sampled_from(["forward", "symmetric"]),
    history=st.sampled_from(["raw", "filtered"]),
    clip=st.booleans(),
)
def test_streaming_equals_batch_equals_the_rule(raw, window, mode, history, clip) -> None:
    n_places = 200 if clip else None
    batch = filter_sequence(np.array(raw, dtype=np.int64), window, mode=mode, history=history, n_places=n_places)
    f = SequenceFilter(window, mode=mode, history=history, n_places=n_places)
    stream = [f.update(i) for i in raw]
    np.testing.assert_array_equal(batch, stream)
    assert stream == reference_filter(raw, window, mode, history, n_places)
    # The first 2a outputs are never touched; clipped outputs stay valid places.
    assert stream[: 2 * window] == raw[: 2 * window]
    if clip:
        assert all(0 <= o < n_places for o in stream)


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"window": 0}, "window must be an integer"),
        ({"window": 2.5}, "window must be an integer"),
        ({"window": 2, "mode": "backward"}, "mode must be one of"),
        ({"window": 2, "history": "smoothed"}, "history must be one of"),
        ({"window": 2, "n_places": 0}, "n_places must be an integer"),
    ],
)
def test_invalid_parameters(kwargs, message: str) -> None:
    with pytest.raises(InvalidParameterError, match=message):
        SequenceFilter(**kwargs)
    with pytest.raises(InvalidParameterError, match=message):
        filter_sequence([1, 2, 3], **kwargs)
