"""The reprojection model of the per-frame accuracy fit: rotations, projection, and the residual
Jacobian against finite differences of the left update it claims to differentiate."""

from __future__ import annotations

import math

import numpy as np
import pytest

from pgt_check.geometry.reprojection import (
    angle_deg,
    angle_deg_batch,
    mean_disp,
    project,
    residuals_jac,
    so3_exp,
    so3_exp_batch,
)
from pgt_check.geometry.transforms import axis_angle_to_rotmat

K = np.array([[500.0, 0.5, 320], [0, 480.0, 240], [0, 0, 1]])


def test_rotations_agree_with_axis_angle_single_and_batched():
    rng = np.random.default_rng(0)
    w = np.vstack([rng.normal(size=(5, 3)) * 0.4, np.zeros((1, 3)), [[1e-12, 0, 0]]])
    batch = so3_exp_batch(w)
    for wi, rb in zip(w, batch, strict=True):
        r = so3_exp(wi)
        th = np.linalg.norm(wi)
        assert np.allclose(rb, r, atol=1e-12)
        assert np.allclose(r @ r.T, np.eye(3), atol=1e-12)
        if th > 1e-9:
            assert np.allclose(r, axis_angle_to_rotmat(wi / th, math.degrees(th)), atol=1e-12)
        assert angle_deg(r) == pytest.approx(math.degrees(th), abs=1e-5)
    assert np.allclose(angle_deg_batch(batch), np.degrees(np.linalg.norm(w, axis=1)), atol=1e-5)


def test_residual_jacobian_matches_finite_differences_of_the_left_update():
    rng = np.random.default_rng(1)
    p = np.c_[rng.uniform(-1, 1, (30, 2)), rng.uniform(2, 5, 30)]
    r, t = so3_exp(np.array([0.02, -0.01, 0.03])), np.array([0.05, -0.02, 0.1])
    obs = project(K, p) + rng.normal(0, 2, (30, 2))
    res, jac = residuals_jac(K, p, obs, r, t)
    assert res.shape == (30, 2) and jac.shape == (30, 2, 6)
    eps = 1e-6
    for i in range(6):
        d = np.zeros(6)
        d[i] = eps
        dr = so3_exp(d[:3])
        moved, _ = residuals_jac(K, p, obs, dr @ r, dr @ t + d[3:])
        assert np.allclose((moved - res) / eps, jac[:, :, i], rtol=1e-4, atol=1e-3)


def test_points_behind_the_camera_give_nan_and_no_mean():
    x = np.array([[0.0, 0.0, 2.0], [0.1, 0.0, -1.0]])
    u = project(K, x)
    assert np.allclose(u[0], K[:2, 2]) and np.all(np.isnan(u[1]))
    behind = -np.abs(np.random.default_rng(2).normal(size=(1, 4, 3)))
    assert np.isnan(mean_disp(K, behind, np.zeros((4, 2)))[0])
    shifted = mean_disp(K, np.array([[[0.0, 0.0, 2.0], [0.0, 0.0, 4.0]]]), K[:2, 2] + [[3, 4]] * 2)
    assert shifted[0] == pytest.approx(5.0)
