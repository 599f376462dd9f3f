"""surgiplan.geometry.boxes answers what the numpy expressions it replaces answer, to the bit."""

from __future__ import annotations

import numpy as np
import pytest
from surgiplan.geometry import boxes


@pytest.mark.parametrize("d", [1, 3, 4, 7])
def test_inside_is_numpys_all_of_the_comparisons(d):
    """Random rows, rows on the boundary, NaN and infinities: the same booleans as ``np.all(..., axis=1)``."""
    rng = np.random.default_rng(d)
    low, high = -rng.random(d), rng.random(d)
    points = rng.uniform(low - 0.1, high + 0.1, size=(500, d))
    points[:20] = low  # on the lower face: inside
    points[20:40] = high
    points[40, 0] = np.nan
    points[41, -1] = np.inf
    points[42, 0] = np.nextafter(low[0], -np.inf)  # just outside
    expected = np.all((points >= low) & (points <= high), axis=1)
    got = boxes.inside(points, low, high)
    assert got.dtype == bool
    np.testing.assert_array_equal(got, expected)
    assert got[:40].all() and not got[40:43].any()
    assert 0 < np.count_nonzero(got[43:]) < 457  # both answers among the random rows
    np.testing.assert_array_equal(boxes.inside(points, -0.5, 0.5), np.all(np.abs(points) <= 0.5, axis=1))
    assert boxes.inside(np.zeros((0, d)), low, high).shape == (0,)


@pytest.mark.parametrize(("seed", "d", "n"), [(0, 3, 1), (1, 3, 2500), (2, 4, 999), (3, 6, 10)])
def test_uniform_draws_the_numbers_of_generator_uniform(seed, d, n):
    """The same numbers, to the bit, as ``Generator.uniform(low, high, size=(n, d))``, and the stream left in the
    same state (the next draw agrees too)."""
    rng = np.random.default_rng(seed)
    low = rng.uniform(-2, 0, d)
    high = low + rng.uniform(1e-3, 3, d)
    a, b = np.random.default_rng(seed + 100), np.random.default_rng(seed + 100)
    np.testing.assert_array_equal(boxes.uniform(a, low, high, n), b.uniform(low, high, size=(n, d)))
    assert a.random() == b.random()
