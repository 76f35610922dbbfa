"""Pose-error sensitivities: the linearised corner error per degree and per scene unit against
the homography the check really fits (synthetic points: the truth is known)."""

from __future__ import annotations

import numpy as np
import pytest

from pgt_check.geometry.sensitivity import corner_sensitivities, frame_sensitivities, sphere_axes

K = np.array([[500.0, 0, 320], [0, 500.0, 240], [0, 0, 1]])


def test_corner_sensitivities_match_the_homography_the_check_fits():
    """The linearised sensitivities equal the corner error of a homography fitted to the
    points' motion under a small real pose change, for rotations and for translations of a
    scene with two depths (parallax: a translation's effect depends on the depths)."""
    import cv2

    from pgt_check.geometry.homography import corner_error
    from pgt_check.geometry.transforms import axis_angle_to_rotmat

    rng = np.random.default_rng(5)
    uv = rng.uniform([0, 0], [640, 480], size=(300, 2))
    z = np.where(uv[:, 0] < 320, 2.0, 5.0)  # a near half and a far half
    p = np.c_[(uv - K[:2, 2]) / K[0, 0], np.ones(len(uv))] * z[:, None]
    axes = sphere_axes(16)
    assert np.allclose(np.linalg.norm(axes, axis=1), 1.0)
    rot, tra = corner_sensitivities(p, K, 640, 480, axes)
    for i in (0, 5, 11):
        for size, moved, per in (
            (1e-3, p @ axis_angle_to_rotmat(axes[i], np.degrees(1e-3)).T, rot[i]),
            (1e-3, p + 1e-3 * axes[i], tra[i]),
        ):
            a = (p @ K.T)[:, :2] / p[:, 2:]
            b = (moved @ K.T)[:, :2] / moved[:, 2:]
            h, _ = cv2.findHomography(a, b, 0)  # least squares, as linearised
            assert corner_error(h, 640, 480) == pytest.approx(per * size, rel=0.05)
    # a roll moves each corner by its distance from the principal point
    roll, _ = corner_sensitivities(p, K, 640, 480, np.array([[0.0, 0.0, 1.0]]))
    corners = np.array([[0, 0], [640, 0], [640, 480], [0, 480]]) - 0.5
    assert roll[0] == pytest.approx(np.linalg.norm(corners - K[:2, 2], axis=1).mean(), rel=1e-3)


def test_frame_sensitivities_scale_with_the_points_depth():
    """At the frame's points a camera shift moves the image as f / depth: twice as far, half the
    pixels per unit; a rotation's pixels per degree do not depend on the depth. The low (5 %)
    quantile over error axes is at most the median."""
    rng = np.random.default_rng(2)
    uv = rng.uniform([0, 0], [640, 480], size=(200, 2))
    ray = np.c_[(uv - K[:2, 2]) / K[0, 0], np.ones(len(uv))]
    near = frame_sensitivities(K, ray * 2.0, uv, 640, 480)
    far = frame_sensitivities(K, ray * 4.0, uv, 640, 480)
    assert near["depth"] == pytest.approx(2.0)
    assert near["points_px_per_unit"] == pytest.approx(2 * far["points_px_per_unit"], rel=1e-6)
    assert near["points_px_per_deg"] == pytest.approx(far["points_px_per_deg"], rel=1e-6)
    assert near["px_per_deg"] == pytest.approx(far["px_per_deg"], rel=1e-6)
    for s in (near, far):
        assert 0 < s["low_px_per_deg"] <= s["px_per_deg"]
        assert 0 < s["low_px_per_unit"] <= s["px_per_unit"]
