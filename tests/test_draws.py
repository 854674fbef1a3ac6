"""sim.draws.uniform: NumPy's Generator.uniform to the bit, and the generator left in the same state."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from sb3_crowdnav.sim.draws import uniform

finite = st.floats(-1e6, 1e6, allow_nan=False, allow_infinity=False)


@settings(max_examples=200, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), low=finite, span=st.floats(0.0, 1e6), as_int=st.booleans())
def test_scalar_bounds_draw_numpys_value(seed, low, span, as_int):
    ours, theirs = np.random.default_rng(seed), np.random.default_rng(seed)
    lo, hi = (int(low), int(low) + int(span)) if as_int else (low, low + span)
    for _ in range(5):
        got = uniform(ours, lo, hi)
        assert isinstance(got, float) and got == theirs.uniform(lo, hi)
    assert ours.random() == theirs.random()  # the same state after the draws


@settings(max_examples=100, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), lows=st.lists(finite, min_size=1, max_size=6),
       span=st.floats(0.0, 1e3), rows=st.integers(1, 5))
def test_array_bounds_and_sizes_draw_numpys_values(seed, lows, span, rows):
    ours, theirs = np.random.default_rng(seed), np.random.default_rng(seed)
    low = np.array(lows)
    high = low + span * np.linspace(0.0, 1.0, len(lows))
    for args in ((low, high), (low, high, (rows, len(lows))), (tuple(low.tolist()), tuple(high.tolist()))):
        got, expected = uniform(ours, *args), theirs.uniform(*args)
        assert got.shape == expected.shape and got.view(np.int64).tolist() == expected.view(np.int64).tolist()
    got, expected = uniform(ours, 0.0, 1.0, (rows, 2)), theirs.uniform(0.0, 1.0, (rows, 2))  # float bounds, a size
    assert got.shape == expected.shape and np.array_equal(got, expected)
    assert ours.random() == theirs.random()
