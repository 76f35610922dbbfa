"""The shift search's significance (``geometry/edges/search.py``)."""

from __future__ import annotations

import numpy as np


def test_null_p_value_on_a_flat_grid_with_one_peak():
    from pgt_check.geometry.edges.search import null_p_value

    rng = np.random.default_rng(0)
    grid = rng.normal(0.3, 0.02, (41, 41)).clip(0.01)
    xs = np.arange(-20, 21) * 2.0
    grid[20, 20] = 0.6
    p, n = null_p_value(grid, xs, xs, (20, 20), 9.0)
    assert p < 1e-3 and n > 50
    grid[20, 20] = 0.31  # no higher than the noise
    assert null_p_value(grid, xs, xs, (20, 20), 9.0)[0] > 0.1
    assert null_p_value(grid[18:23, 18:23], xs[18:23], xs[18:23], (2, 2), 9.0) == (1.0, 0)
