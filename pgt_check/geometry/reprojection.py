"""The pinhole reprojection model the per-frame accuracy fit and its sensitivities share.

A pose error is a left update ``x -> exp(dw) x + dt`` of camera points ``x = R p + t``; these
are its rotations (Rodrigues, single and batched), the projection and the residual Jacobian.
Split out of ``frame_accuracy.py`` (its size) so that ``sensitivity.py`` uses the same model.
"""

from __future__ import annotations

import math

import numpy as np


def skew(v: np.ndarray) -> np.ndarray:
    """(..., 3) -> (..., 3, 3) cross-product matrices."""
    k = np.zeros(v.shape[:-1] + (3, 3))
    k[..., 0, 1], k[..., 0, 2], k[..., 1, 2] = -v[..., 2], v[..., 1], -v[..., 0]
    k[..., 1, 0], k[..., 2, 0], k[..., 2, 1] = v[..., 2], -v[..., 1], v[..., 0]
    return k


def so3_exp(w: np.ndarray) -> np.ndarray:
    """Rotation vector (3,) -> (3, 3) (Rodrigues)."""
    th = float(np.linalg.norm(w))
    k = skew(np.asarray(w, np.float64))
    if th < 1e-10:
        return np.eye(3) + k
    return np.eye(3) + math.sin(th) / th * k + (1 - math.cos(th)) / th**2 * (k @ k)


def angle_deg(r: np.ndarray) -> float:
    """(3, 3) rotation -> its angle in degrees."""
    return math.degrees(math.acos(float(np.clip((np.trace(r) - 1) / 2, -1.0, 1.0))))


def project(k: np.ndarray, x: np.ndarray) -> np.ndarray:
    """(N, 3) camera points -> (N, 2) pixels (points behind the camera give NaN)."""
    z = np.where(x[:, 2] > 1e-9, x[:, 2], np.nan)
    u = x @ k.T
    return u[:, :2] / z[:, None]


def residuals_jac(
    k: np.ndarray, p: np.ndarray, obs: np.ndarray, r: np.ndarray, t: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Residuals (N, 2) and Jacobians (N, 2, 6) w.r.t. a left update (dw, dt):
    x -> exp(dw) x + dt with x = R p + t."""
    x = p @ r.T + t
    res = project(k, x) - obs
    z = x[:, 2]
    fx, fy, s = k[0, 0], k[1, 1], k[0, 1]
    dproj = np.zeros((len(x), 2, 3))
    dproj[:, 0, 0] = fx / z
    dproj[:, 0, 1] = s / z
    dproj[:, 0, 2] = -(fx * x[:, 0] + s * x[:, 1]) / z**2
    dproj[:, 1, 1] = fy / z
    dproj[:, 1, 2] = -fy * x[:, 1] / z**2
    jac = np.concatenate([dproj @ -skew(x), dproj], axis=2)
    return res, jac


def so3_exp_batch(w: np.ndarray) -> np.ndarray:
    """(B, 3) rotation vectors -> (B, 3, 3) (Rodrigues, as ``_exp``)."""
    th = np.linalg.norm(w, axis=1)
    k = skew(w)
    small = th < 1e-10
    ts = np.where(small, 1.0, th)
    a = np.where(small, 1.0, np.sin(ts) / ts)[:, None, None]
    b = np.where(small, 0.0, (1 - np.cos(ts)) / ts**2)[:, None, None]
    return np.eye(3) + a * k + b * (k @ k)


def angle_deg_batch(r: np.ndarray) -> np.ndarray:
    """(B, 3, 3) rotations -> (B,) angles in degrees (as ``_angle_deg``)."""
    return np.degrees(np.arccos(np.clip((np.trace(r, axis1=1, axis2=2) - 1) / 2, -1.0, 1.0)))


def mean_disp(K: np.ndarray, x: np.ndarray, ref: np.ndarray) -> np.ndarray:
    """(B,) mean finite distance of the projections of (B, N, 3) camera points to ``ref``
    (N, 2) (NaN where none is finite: every point behind the camera)."""
    z = np.where(x[..., 2] > 1e-9, x[..., 2], np.nan)
    u = x @ K.T
    d = np.linalg.norm(u[..., :2] / z[..., None] - ref, axis=-1)
    ok = np.isfinite(d)
    n = ok.sum(axis=1)
    total = np.where(ok, d, 0.0).sum(axis=1)
    return np.where(n > 0, total / np.maximum(n, 1), np.nan)
