"""Synthetic evidence for the shared-error estimators: 40 cameras at 3 m around random points
(2-4 m deep), f=525, 640x480, ~100 correspondences per frame, 1 px noise, 30 % outliers, with
shared errors injected (world similarity, camera rotation / translation, intrinsics, drift).
Shared by the tests of ``pgt_check.geometry.shared_errors`` (imported by its module path)."""

from __future__ import annotations

import numpy as np

from pgt_check.geometry.shared_errors import FrameEvidence
from pgt_check.geometry.transforms import axis_angle_to_rotmat

THRESHOLD_PX = 2.0

K = np.array([[525.0, 0, 319.5], [0, 525.0, 239.5], [0, 0, 1]])
W, H = 640, 480


def look_at(centre: np.ndarray, target: np.ndarray) -> np.ndarray:
    fwd = target - centre
    fwd /= np.linalg.norm(fwd)
    right = np.cross(fwd, [0.0, 0.0, 1.0])
    right /= np.linalg.norm(right)
    down = np.cross(fwd, right)
    pose = np.eye(4)
    pose[:3, :3] = np.stack([right, down, fwd], axis=1)
    pose[:3, 3] = centre
    return pose


def trajectory(n: int, rng: np.random.Generator, layout: str = "loop") -> list[np.ndarray]:
    """world_from_cam poses: a loop of radius 3 m around the scene, or a short forward line."""
    poses = []
    for i in range(n):
        if layout == "loop":
            a = 2 * np.pi * i / n
            c = np.array([3 * np.cos(a), 3 * np.sin(a), 0.4 * np.sin(3 * a)])
            target = rng.normal(scale=0.3, size=3)
        else:  # all cameras look the same way from nearly the same place
            c = np.array([-3.0, 0.1 * i / n, 0.0]) + rng.normal(scale=0.01, size=3)
            target = np.array([0.0, 0.1 * i / n, 0.0]) + rng.normal(scale=0.02, size=3)
        poses.append(look_at(c, target))
    return poses


def similarity(angle_deg: float, axis, t, scale: float = 1.0, centre=(0, 0, 0)) -> np.ndarray:
    """4x4 similarity X -> scale R (X - centre) + centre + t."""
    r = axis_angle_to_rotmat(np.asarray(axis, float), angle_deg)
    m = np.eye(4)
    m[:3, :3] = scale * r
    m[:3, 3] = np.asarray(centre) + np.asarray(t) - scale * r @ np.asarray(centre)
    return m


def apply(sim: np.ndarray, pose: np.ndarray) -> np.ndarray:
    """Rigid pose with centre mapped by ``sim`` and rotation rotated by its rotation."""
    s = np.cbrt(np.linalg.det(sim[:3, :3]))
    out = np.eye(4)
    out[:3, :3] = sim[:3, :3] / s @ pose[:3, :3]
    out[:3, 3] = sim[:3, :3] @ pose[:3, 3] + sim[:3, 3]
    return out


def make_evidence(
    seed: int = 0,
    n_frames: int = 40,
    n_points: int = 100,
    noise_px: float = 1.0,
    outliers: float = 0.3,
    layout: str = "loop",
    world_error=None,  # callable(frame position) -> 4x4 similarity C (true = C @ checked)
    cam_rotation: np.ndarray | None = None,  # (3, 3) true_cam_from_checked_cam
    focal_scale: float = 1.0,
    pp_shift=(0.0, 0.0),
    offset=(0.0, 0.0, 0.0),
    cam_translation=(0.0, 0.0, 0.0),  # true_cam_from_checked_cam translation (camera frame)
) -> list[FrameEvidence]:
    rng = np.random.default_rng(seed)
    scene = rng.uniform(-1, 1, size=(4000, 3))
    k_true = K.copy()
    k_true[0, 0] *= focal_scale
    k_true[1, 1] *= focal_scale
    k_true[:2, 2] += pp_shift
    rc = np.eye(3) if cam_rotation is None else cam_rotation
    off = np.asarray(offset, float)
    out = []
    for i, true in enumerate(trajectory(n_frames, rng, layout)):
        checked = true
        if world_error is not None:
            checked = apply(np.linalg.inv(world_error(i)), true)
        xc = (scene - true[:3, 3]) @ true[:3, :3]
        xc = xc @ rc.T + np.asarray(cam_translation, float)
        pix = xc @ k_true.T
        uv = pix[:, :2] / pix[:, 2:]
        vis = np.flatnonzero(
            (xc[:, 2] > 0.1) & (uv[:, 0] >= 0) & (uv[:, 0] < W) & (uv[:, 1] >= 0) & (uv[:, 1] < H)
        )
        pick = rng.choice(vis, size=min(n_points, len(vis)), replace=False)
        obs = uv[pick] + rng.normal(scale=noise_px, size=(len(pick), 2))
        bad = rng.random(len(pick)) < outliers
        obs[bad] = rng.uniform([0, 0], [W, H], size=(int(bad.sum()), 2))
        pose = checked.copy()
        pose[:3, 3] += off
        out.append(FrameEvidence(f"f{i:03d}", i, "cam", pose, K, W, H, obs, scene[pick] + off))
    return out


def _within(value: float, truth: float, rel: float = 0.3) -> bool:
    return abs(value - truth) <= rel * abs(truth)
