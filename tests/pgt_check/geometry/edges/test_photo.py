"""``photo_edges`` (``geometry/edges/photo.py``): sub-pixel edges of drawn photos and their
oriented distance maps."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from pgt_check.geometry.edges import photo_edges


def test_photo_edges_subpixel_position_and_orientation():
    x0 = 40.3  # the step sits between pixel centres; pixel i covers [i - .5, i + .5]
    xs = np.arange(96, dtype=np.float64)
    row = np.clip(xs + 0.5 - x0, 0.0, 1.0) * 0.6 + 0.2
    img = np.repeat(np.repeat(row[None, :], 64, axis=0)[:, :, None], 3, axis=2)
    pe = photo_edges(img.astype(np.float32))
    inner = (pe.points[:, 1] > 3) & (pe.points[:, 1] < 60)
    assert inner.sum() > 50
    np.testing.assert_allclose(pe.points[inner, 0], x0, atol=0.15)
    np.testing.assert_allclose(np.abs(pe.normals[inner, 0]), 1.0, atol=1e-3)
    assert pe.orientation.shape == (64, 96)


def test_oriented_distance_and_nearest_match_brute_force():
    rng = np.random.default_rng(0)
    img = np.full((80, 100), 0.5, dtype=np.float32)
    for _ in range(12):  # random rectangles and lines: edges of all orientations
        x, y = rng.integers(0, 90), rng.integers(0, 70)
        cv2.rectangle(
            img,
            (int(x), int(y)),
            (int(x + rng.integers(5, 30)), int(y + rng.integers(5, 30))),
            float(rng.uniform(0, 1)),
            -1,
        )
        cv2.line(
            img,
            tuple(int(v) for v in rng.integers(0, 80, 2)),
            tuple(int(v) for v in rng.integers(0, 80, 2)),
            float(rng.uniform(0, 1)),
            2,
        )
    pe = photo_edges(np.repeat(img[:, :, None], 3, axis=2))
    assert len(pe) > 100
    n_bins = pe.n_bins
    qy, qx = rng.integers(0, 80, 300), rng.integers(0, 100, 300)
    qb = rng.integers(0, n_bins, 300)
    d, e = pe.compatible_nearest(qb, qx, qy)
    for i in range(300):
        diff = (pe.bins - qb[i] + n_bins) % n_bins
        compat = np.isin(diff, [0, 1, n_bins - 1])
        dist = np.hypot(pe.pixels[compat, 0] - qx[i], pe.pixels[compat, 1] - qy[i])
        assert d[i] == pytest.approx(dist.min(), abs=0.1 + 0.03 * dist.min())  # mask-5 approx.
        assert compat[e[i]]
        assert np.hypot(*(pe.pixels[e[i]] - [qx[i], qy[i]])) == pytest.approx(
            d[i], abs=0.1 + 0.03 * d[i]
        )
    np.testing.assert_array_equal(pe.oriented_nearest[qb, qy, qx], e)
    # unoriented maps: distance to the nearest edge pixel of any orientation
    all_d = np.hypot(pe.pixels[:, 0][None] - qx[:, None], pe.pixels[:, 1][None] - qy[:, None])
    np.testing.assert_allclose(pe.dist[qy, qx], all_d.min(axis=1), atol=0.6)
    assert np.all(pe.edges[pe.pixels[pe.nearest[qy, qx], 1], pe.pixels[pe.nearest[qy, qx], 0]])


def test_photo_edges_of_a_blank_image():
    pe = photo_edges(np.full((40, 50, 3), 0.4, dtype=np.float32))
    assert len(pe) == 0
    assert np.all(np.isinf(pe.oriented_dist))
    with pytest.raises(ValueError, match="photo_rgb"):
        photo_edges(np.zeros((4, 5, 2)))
