"""The tile-shift start of the refinement (``geometry/edges/tiles.py``)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from pgt_check.geometry.edges import (
    EdgeAlignConfig,
    EdgeProblem,
    align_edges,
    geometric_edges,
    photo_edges,
)
from tests.pgt_check.geometry.edges.drawn import (
    H,
    K,
    W,
    blocks_depth,
    corner_distance,
    photo_from_depth,
    translation,
)


def _zoom(zoom: float, dx: float, dy: float) -> np.ndarray:
    return translation(W / 2 + dx, H / 2 + dy) @ np.diag([zoom, zoom, 1.0]) @ translation(-W / 2, -H / 2)


@pytest.mark.parametrize(("zoom", "seed"), [(1.08, 2), (1.10, 2), (1.10, 3)])
def test_a_zoom_larger_than_tau_is_recovered_from_the_tile_start(zoom, seed):
    """A camera moved towards the scene zooms the image: +-13-16 px across this view against
    tau = 3 px. From the best shift alone the refinement treats the far-off edges as outliers
    and stops short (8-20 px off at the corners); the affine map of the 3 x 3 tile shifts
    starts it within reach."""
    from pgt_check.geometry.edges.search import bins_of
    from pgt_check.geometry.edges.tiles import tile_start

    warp = _zoom(zoom, 9.0, -6.0)
    z = blocks_depth(seed=seed, n=10)
    re, pe = geometric_edges(z, K), photo_edges(photo_from_depth(z, warp))
    tiles = EdgeAlignConfig(tile_grid=3)
    al = align_edges(re, pe, tiles)
    assert al.success, al.reason
    assert corner_distance(al.photo_from_render, warp) < 0.6
    without = align_edges(re, pe)  # the default: no tile start
    assert corner_distance(without.photo_from_render, warp) > 3.0
    # the shift search alone reads the zoom as several peaks (ambiguous); judged again around
    # the refined alignment, it is one
    assert not al.ambiguous
    # the start itself carries the zoom: nearer the truth than the best shift
    shift = np.array(al.shift)
    start = tile_start(EdgeProblem(re, pe, bins_of(re.normals, pe.n_bins), 3.0, tiles), shift)
    assert start is not None
    assert corner_distance(start, warp) < 0.7 * corner_distance(translation(*shift), warp)


def test_tile_start_off_or_without_enough_tiles():
    from pgt_check.geometry.edges.search import bins_of
    from pgt_check.geometry.edges.tiles import tile_start

    z = blocks_depth(seed=1)
    warp = translation(5.0, -3.0)
    re, pe = geometric_edges(z, K), photo_edges(photo_from_depth(z, warp))
    bins = bins_of(re.normals, pe.n_bins)
    shift = np.array([5.0, -3.0])
    tiles = EdgeAlignConfig(tile_grid=3)
    assert tile_start(EdgeProblem(re, pe, bins, 3.0, EdgeAlignConfig()), shift) is None  # off by default
    # a shift: every tile finds it, the affine map is that shift
    h = tile_start(EdgeProblem(re, pe, bins, 3.0, tiles), shift)
    assert h is not None and corner_distance(h, warp) < 1.5
    # edges in one corner only: fewer than 4 tiles with enough points
    corner = re.points[:, 0] < W / 3
    corner &= re.points[:, 1] < H / 3
    few = dataclasses.replace(
        re, **{k: getattr(re, k)[corner] for k in ("points", "normals", "depth", "kind")}
    )
    assert tile_start(EdgeProblem(few, pe, bins[corner], 3.0, tiles), shift) is None
