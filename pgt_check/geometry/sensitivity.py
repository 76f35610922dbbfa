"""How many pixels a pose error moves a frame's check: px per degree and per scene unit.

At the frame's evidence points (what the run-level fits measure) and at the image corners as
the check's homography measures them, over error axes spread on the sphere (a rotation moves
the corners by the same amount whatever the scene; a translation's depends on the points'
depths). Turns pixel thresholds into pose units (``FrameAccuracy``'s sensitivity fields).
Split out of ``frame_accuracy.py`` (its size).
"""

from __future__ import annotations

import math

import numpy as np

from pgt_check.common.checks import check_shape
from pgt_check.geometry.reprojection import project, residuals_jac

#: quantile over error axes of the ``low_*`` sensitivities (95 % of axes move the corners more)
LOW_AXIS_QUANTILE = 0.05


def sphere_axes(n: int = 256) -> np.ndarray:
    """(n, 3) unit vectors spread evenly over the sphere (Fibonacci lattice; deterministic)."""
    i = np.arange(n) + 0.5
    z = 1.0 - 2.0 * i / n
    phi = math.pi * (3.0 - math.sqrt(5.0)) * i
    rho = np.sqrt(1.0 - z * z)
    return np.stack([rho * np.cos(phi), rho * np.sin(phi), z], axis=1)


def _homography_jac(x: np.ndarray) -> np.ndarray:
    """(N, 2) normalised points -> (N, 2, 8): the motion of each point per parameter of a
    homography at the identity (h11-1, h12, h13, h21, h22-1, h23, h31, h32)."""
    a = np.zeros((len(x), 2, 8))
    u, v = x[:, 0], x[:, 1]
    a[:, 0, 0], a[:, 0, 1], a[:, 0, 2] = u, v, 1.0
    a[:, 1, 3], a[:, 1, 4], a[:, 1, 5] = u, v, 1.0
    a[:, 0, 6], a[:, 0, 7] = -u * u, -u * v
    a[:, 1, 6], a[:, 1, 7] = -u * v, -v * v
    return a


def corner_sensitivities(
    pts_cam: np.ndarray, K: np.ndarray, width: int, height: int, axes: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Corner error (px) per radian of rotation about each of ``axes`` (M, 3) and per scene
    unit of camera translation along each, as the check measures a small pose error: the image
    motion of the points ``pts_cam`` (N, 3) fitted by a homography (least squares, linearised
    at the identity), its displacement averaged over the four image corners. A rotation moves
    the corners by the same amount whatever the scene; a translation's depends on the points'
    depths, which a single sensitivity at one depth misses. Returns (rot (M,), trans (M,))."""
    check_shape("axes", axes, (None, 3))
    x = pts_cam[pts_cam[:, 2] > 0]
    _, j = residuals_jac(K, x, np.zeros((len(x), 2)), np.eye(3), np.zeros(3))  # (N, 2, 6)
    centre = np.array([(width - 1) / 2, (height - 1) / 2])
    s = max(width, height) / 2
    a = _homography_jac((project(K, x) - centre) / s).reshape(-1, 8)
    h = np.linalg.lstsq(a, j.reshape(-1, 6) / s, rcond=None)[0]  # (8, 6)
    corners = np.array([[0, 0], [width, 0], [width, height], [0, height]], np.float64) - 0.5
    c = _homography_jac((corners - centre) / s).reshape(-1, 8) @ h * s  # (8, 6) px per unit
    out = []
    for block in (c[:, :3], c[:, 3:]):
        disp = (block @ axes.T).reshape(4, 2, -1)  # corner, xy, axis
        out.append(np.linalg.norm(disp, axis=1).mean(axis=0))
    return out[0], out[1]


def frame_sensitivities(
    K: np.ndarray, pts: np.ndarray, obs: np.ndarray, width: int, height: int
) -> dict[str, float]:
    """The ``FrameAccuracy`` sensitivity fields and depth of the inlier points ``pts`` (N, 3)
    observed at ``obs`` (N, 2)."""
    # mean |du| per degree about each camera axis and per unit along each at the frame's
    # points; at the image corners as the check measures them, over error axes
    _, j0 = residuals_jac(K, pts, obs, np.eye(3), np.zeros(3))
    per_axis = np.linalg.norm(j0, axis=1).mean(axis=0)  # (6,) px per rad / per unit
    zc = float(np.median(pts[:, 2]))
    rot_c, tra_c = corner_sensitivities(pts, K, width, height, sphere_axes())
    return dict(
        px_per_deg=float(np.median(rot_c) * math.pi / 180),
        px_per_unit=float(np.median(tra_c)),
        low_px_per_deg=float(np.quantile(rot_c, LOW_AXIS_QUANTILE) * math.pi / 180),
        low_px_per_unit=float(np.quantile(tra_c, LOW_AXIS_QUANTILE)),
        points_px_per_deg=float(per_axis[:3].mean() * math.pi / 180),
        points_px_per_unit=float(per_axis[3:].mean()),
        depth=zc,
    )
