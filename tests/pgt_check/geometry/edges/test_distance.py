"""Labelled distance transforms of the photo edge maps (``geometry/edges/distance.py``)
against brute force."""

from __future__ import annotations

import numpy as np

from pgt_check.geometry.edges.distance import distance_with_labels, row_major_index


def test_row_major_index():
    pixels = np.array([[0, 0], [3, 0], [0, 2], [4.0, 1.0]])  # (x, y)
    np.testing.assert_array_equal(row_major_index(pixels, 5), [0, 3, 10, 9])


def test_distances_and_labels_name_the_nearest_true_pixel():
    rng = np.random.default_rng(0)
    mask = rng.random((30, 40)) < 0.02
    dist, labels, order = distance_with_labels(mask)
    assert dist.shape == labels.shape == mask.shape
    np.testing.assert_array_equal(order, np.flatnonzero(mask.ravel()))
    ys, xs = np.nonzero(mask)
    yy, xx = np.mgrid[0:30, 0:40]
    brute = np.min(np.hypot(yy[..., None] - ys, xx[..., None] - xs), axis=2)
    tol = 0.1 + 0.03 * brute  # the mask-5 approximation of the Euclidean distance
    assert np.all(np.abs(dist - brute) <= tol)
    assert np.all(dist[mask] == 0)
    # each label names (row-major, through ``order``) an edge pixel at that distance
    nearest = order[labels - 1]
    ny, nx = np.divmod(nearest, 40)
    assert np.all(mask[ny, nx])
    assert np.all(np.abs(np.hypot(ny - yy, nx - xx) - dist) <= tol)


def test_an_empty_mask_is_infinitely_far_with_no_labels():
    dist, labels, order = distance_with_labels(np.zeros((6, 7), bool))
    assert np.all(np.isinf(dist)) and not labels.any() and len(order) == 0
