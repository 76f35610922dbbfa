"""Rigid transforms and quaternions (Hamilton, scalar first), all float64."""

from __future__ import annotations

import logging

import numpy as np

from pgt_check.common.checks import check_shape

logger = logging.getLogger(__name__)

#: quaternions whose norm is further than this from 1 are rejected (closer ones are normalised)
QUAT_NORM_TOLERANCE = 1e-2


class QuaternionError(ValueError):
    """A quaternion that is not finite or too far from unit norm."""


def normalize_quaternion(q: np.ndarray, tolerance: float = QUAT_NORM_TOLERANCE) -> np.ndarray:
    """Return q / |q|; raise QuaternionError if |q| is non-finite or off 1 by more than tolerance.

    q: (4,) (w, x, y, z). Deviations above 1e-6 are logged at DEBUG.
    """
    q = np.asarray(q, dtype=np.float64)
    check_shape("quaternion", q, (4,))
    if not np.all(np.isfinite(q)):
        raise QuaternionError(f"quaternion is not finite: {q.tolist()}")
    n = float(np.linalg.norm(q))
    if abs(n - 1.0) > tolerance:
        raise QuaternionError(f"quaternion norm {n:.6g} is not 1 (tolerance {tolerance})")
    if abs(n - 1.0) > 1e-6:
        logger.debug("normalising quaternion with norm %.9f", n)
    return q / n


def quat_to_rotmat(q: np.ndarray, tolerance: float = QUAT_NORM_TOLERANCE) -> np.ndarray:
    """(4,) Hamilton quaternion (w, x, y, z) -> (3, 3) rotation matrix."""
    w, x, y, z = normalize_quaternion(q, tolerance)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def rotmat_to_quat(r: np.ndarray) -> np.ndarray:
    """(3, 3) rotation -> (4,) Hamilton quaternion (w, x, y, z) with w >= 0."""
    r = np.asarray(r, dtype=np.float64)
    check_shape("rotation", r, (3, 3))
    # Shepperd's method on the largest diagonal element, numerically stable everywhere.
    t = np.trace(r)
    d = np.array([t, r[0, 0], r[1, 1], r[2, 2]])
    i = int(np.argmax(d))
    if i == 0:
        s = np.sqrt(1.0 + t) * 2
        q = [0.25 * s, (r[2, 1] - r[1, 2]) / s, (r[0, 2] - r[2, 0]) / s, (r[1, 0] - r[0, 1]) / s]
    elif i == 1:
        s = np.sqrt(1.0 + r[0, 0] - r[1, 1] - r[2, 2]) * 2
        q = [(r[2, 1] - r[1, 2]) / s, 0.25 * s, (r[0, 1] + r[1, 0]) / s, (r[0, 2] + r[2, 0]) / s]
    elif i == 2:
        s = np.sqrt(1.0 + r[1, 1] - r[0, 0] - r[2, 2]) * 2
        q = [(r[0, 2] - r[2, 0]) / s, (r[0, 1] + r[1, 0]) / s, 0.25 * s, (r[1, 2] + r[2, 1]) / s]
    else:
        s = np.sqrt(1.0 + r[2, 2] - r[0, 0] - r[1, 1]) * 2
        q = [(r[1, 0] - r[0, 1]) / s, (r[0, 2] + r[2, 0]) / s, (r[1, 2] + r[2, 1]) / s, 0.25 * s]
    quat = np.asarray(q)
    quat /= np.linalg.norm(quat)
    return -quat if quat[0] < 0 else quat


def make_rigid(rotation: np.ndarray, translation: np.ndarray) -> np.ndarray:
    """(3, 3) rotation + (3,) translation -> (4, 4) float64 rigid transform."""
    rotation = np.asarray(rotation, dtype=np.float64)
    translation = np.asarray(translation, dtype=np.float64).reshape(-1)
    check_shape("rotation", rotation, (3, 3))
    check_shape("translation", translation, (3,))
    m = np.eye(4)
    m[:3, :3] = rotation
    m[:3, 3] = translation
    return m


def invert_rigid(a_from_b: np.ndarray) -> np.ndarray:
    """(4, 4) rigid a_from_b -> b_from_a, exactly (R^T, -R^T t)."""
    a_from_b = np.asarray(a_from_b, dtype=np.float64)
    check_shape("rigid transform", a_from_b, (4, 4))
    r = a_from_b[:3, :3]
    t = a_from_b[:3, 3]
    return make_rigid(r.T, -r.T @ t)


def apply_rigid(a_from_b: np.ndarray, points_b: np.ndarray) -> np.ndarray:
    """Transform (N, 3) points in frame b into frame a."""
    points_b = np.asarray(points_b, dtype=np.float64)
    check_shape("points", points_b, (None, 3))
    return points_b @ a_from_b[:3, :3].T + a_from_b[:3, 3]


def move_pose(world_from_cam: np.ndarray, moved_from_world: np.ndarray) -> np.ndarray:
    """One (4, 4) pose moved by a rigid / similarity world transform (4, 4): the centre mapped
    by it, the rotation by its rotation part (a scale leaves the camera's axes alone). Returns a
    rigid (4, 4) world_from_cam (a registration correction applied to a pose)."""
    world_from_cam = np.asarray(world_from_cam, dtype=np.float64)
    moved_from_world = np.asarray(moved_from_world, dtype=np.float64)
    check_shape("world_from_cam", world_from_cam, (4, 4))
    check_shape("moved_from_world", moved_from_world, (4, 4))
    det = float(np.linalg.det(moved_from_world[:3, :3]))
    if not det > 0:
        raise ValueError(f"moved_from_world: not a rotation times a positive scale (det {det})")
    s = float(np.cbrt(det))
    out = np.eye(4)
    out[:3, :3] = (moved_from_world[:3, :3] / s) @ world_from_cam[:3, :3]
    out[:3, 3] = moved_from_world[:3, :3] @ world_from_cam[:3, 3] + moved_from_world[:3, 3]
    return out


def rotation_angle_deg(r: np.ndarray) -> float:
    """Geodesic angle of a (3, 3) rotation, in degrees (clipped, stable near 0 and 180)."""
    r = np.asarray(r, dtype=np.float64)
    c = np.clip((np.trace(r) - 1.0) / 2.0, -1.0, 1.0)
    return float(np.degrees(np.arccos(c)))


def axis_angle_to_rotmat(axis: np.ndarray, angle_deg: float) -> np.ndarray:
    """Rodrigues: unit axis (3,) and angle in degrees -> (3, 3) rotation."""
    axis = np.asarray(axis, dtype=np.float64)
    check_shape("axis", axis, (3,))
    n = np.linalg.norm(axis)
    if n == 0 or not np.isfinite(n):
        raise ValueError("rotation axis must be a finite non-zero vector")
    k = axis / n
    a = np.radians(angle_deg)
    kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(a) * kx + (1 - np.cos(a)) * (kx @ kx)


def pose_difference(world_from_cam_a: np.ndarray, world_from_cam_b: np.ndarray) -> tuple[float, float]:
    """(centre distance, rotation angle in degrees) between two world_from_cam poses."""
    dt = float(np.linalg.norm(world_from_cam_a[:3, 3] - world_from_cam_b[:3, 3]))
    dr = rotation_angle_deg(world_from_cam_a[:3, :3].T @ world_from_cam_b[:3, :3])
    return dt, dr
