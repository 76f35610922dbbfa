"""``geometric_edges`` (``geometry/edges/render.py``): silhouettes, borders and creases of
analytic depth maps."""

from __future__ import annotations

import numpy as np
import pytest

from pgt_check.geometry.edges import (
    KIND_BORDER,
    KIND_CREASE,
    KIND_OCCLUSION,
    RenderEdgeConfig,
    geometric_edges,
)
from tests.pgt_check.geometry.edges.drawn import K, blocks_depth


def test_occlusion_edges_are_midpoints_with_near_depth():
    z = np.full((60, 80), 3.0, dtype=np.float32)
    z[20:40, 30:50] = 1.0  # a near square: columns 30..49, rows 20..39
    re = geometric_edges(z, K)
    assert re.n_detected == len(re)
    assert set(np.unique(re.kind)) == {KIND_OCCLUSION}  # a plane: no creases, no borders
    # every point sits on the square's outline (pixel boundaries at 29.5 / 49.5, 19.5 / 39.5)
    x, y = re.points[:, 0], re.points[:, 1]
    on_v = np.isin(x, [29.5, 49.5]) & (y >= 20) & (y <= 39)
    on_h = np.isin(y, [19.5, 39.5]) & (x >= 30) & (x <= 49)
    assert np.all(on_v | on_h)
    # the whole outline, once per pixel (80 pair midpoints; one corner pair rounds to the
    # same pixel and is kept once)
    assert on_v.sum() >= 39 and on_h.sum() >= 39 and len(re) == 79
    np.testing.assert_allclose(re.depth, 1.0)
    # normals across the edge: (+-1, 0) on vertical sides, (0, +-1) on horizontal sides (away
    # from the corners, where the structure tensor mixes both)
    mid_v = on_v & (y > 23) & (y < 36)
    mid_h = on_h & (x > 33) & (x < 46)
    assert np.all(np.abs(re.normals[mid_v, 0]) > 0.99)
    assert np.all(np.abs(re.normals[mid_h, 1]) > 0.99)


def test_background_border_and_no_edges_on_a_slanted_plane():
    h, w = 60, 80
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    # plane Z = 3 + 0.8 X (steeply slanted): 1/z is affine in the pixel coordinates
    xn = (xx - K[0, 2]) / K[0, 0]
    z = (3.0 / (1.0 - 0.8 * xn)).astype(np.float32)
    assert len(geometric_edges(z, K)) == 0
    z[:, 50:] = 0.0  # no surface on the right: a mesh border at x = 49.5
    re = geometric_edges(z, K)
    assert set(np.unique(re.kind)) == {KIND_BORDER}
    np.testing.assert_allclose(re.points[:, 0], 49.5)
    np.testing.assert_allclose(re.depth, z[re.points[:, 1].astype(int), 49])
    assert len(geometric_edges(z, K, RenderEdgeConfig(include_borders=False))) == 0


def test_crease_of_a_folded_surface_is_one_pixel_wide():
    h, w = 60, 81
    cx = 40.0
    k = np.array([[100.0, 0, cx], [0, 100.0, 29.5], [0, 0, 1]])
    xx = np.arange(w, dtype=np.float64)[None, :].repeat(h, axis=0)
    xn = (xx - cx) / 100.0
    z = (3.0 / (1.0 + np.abs(xn))).astype(np.float32)  # Z = 3 - |X|: a 90 degree ridge
    re = geometric_edges(z, k)
    assert len(re) > 0
    assert set(np.unique(re.kind)) == {KIND_CREASE}
    np.testing.assert_array_equal(re.points[:, 0], cx)  # exactly the ridge column, one wide
    assert len(re) >= h - 2 * 4  # the whole ridge except the margins of the normals
    np.testing.assert_allclose(re.depth, 3.0, rtol=1e-5)
    # a shallow fold (10 degrees) is no crease
    z_flat = (3.0 / (1.0 + 0.09 * np.abs(xn))).astype(np.float32)
    assert len(geometric_edges(z_flat, k)) == 0


def test_render_edges_subsample_and_input_checks():
    z = blocks_depth()
    full = geometric_edges(z, K, RenderEdgeConfig(max_points=None))
    capped = geometric_edges(z, K, RenderEdgeConfig(max_points=200, seed=3))
    assert len(capped) == 200 and capped.n_detected == full.n_detected > 200
    again = geometric_edges(z, K, RenderEdgeConfig(max_points=200, seed=3))
    np.testing.assert_array_equal(capped.points, again.points)  # seeded
    with pytest.raises(ValueError, match="depth"):
        geometric_edges(np.zeros((4, 5, 1)), K)
    with pytest.raises(ValueError, match="camera_K"):
        geometric_edges(z, np.eye(2))
    # NaN / inf / negative depths are "no surface", not crashes
    bad = z.copy()
    bad[:5] = np.nan
    bad[5:8] = -1.0
    bad[8:10] = np.inf
    re = geometric_edges(bad, K)
    assert np.all(re.kind[re.points[:, 1] < 9.5] == KIND_BORDER)
    assert np.any(re.points[:, 1] == 9.5)  # the border to the first valid row
