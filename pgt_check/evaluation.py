"""Evaluation helpers shared by tests and benchmarks: pose perturbation and ROC-AUC."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pgt_check.geometry.transforms import axis_angle_to_rotmat
from pgt_check.types import Frame, Trajectory, check_shape


@dataclass(frozen=True)
class Perturbation:
    """An injected pose error: rotation (deg) about a random axis through the camera centre and
    a camera-centre translation (scene units) in a random direction."""

    frame_id: str
    rotation_deg: float
    translation: float


def perturb_pose(
    world_from_cam: np.ndarray, rotation_deg: float, translation: float, rng: np.random.Generator
) -> np.ndarray:
    """Return world_from_cam with a random-axis rotation (camera frame) and a centre shift."""
    world_from_cam = np.asarray(world_from_cam, dtype=np.float64)
    check_shape("world_from_cam", world_from_cam, (4, 4))
    axis = rng.normal(size=3)
    direction = rng.normal(size=3)
    direction /= np.linalg.norm(direction)
    out = world_from_cam.copy()
    out[:3, :3] = world_from_cam[:3, :3] @ axis_angle_to_rotmat(axis, rotation_deg)
    out[:3, 3] = world_from_cam[:3, 3] + translation * direction
    return out


def perturb_trajectory(
    trajectory: Trajectory,
    fraction: float,
    rotation_deg: tuple[float, float],
    translation: tuple[float, float],
    seed: int = 0,
) -> tuple[Trajectory, list[Perturbation]]:
    """Perturb a random ``fraction`` of frames with rotation and translation drawn uniformly
    from the given (low, high) ranges. Returns the new trajectory and what was injected."""
    rng = np.random.default_rng(seed)
    n = len(trajectory)
    k = int(round(fraction * n))
    chosen = set(rng.choice(n, size=k, replace=False).tolist()) if k else set()
    frames: list[Frame] = []
    injected: list[Perturbation] = []
    for i, f in enumerate(trajectory.frames):
        if i in chosen:
            r = float(rng.uniform(*rotation_deg))
            t = float(rng.uniform(*translation))
            frames.append(f.with_pose(perturb_pose(f.world_from_cam, r, t, rng)))
            injected.append(Perturbation(f.frame_id, r, t))
        else:
            frames.append(f)
    return (
        Trajectory(tuple(frames), trajectory.source, trajectory.format, dict(trajectory.metadata)),
        injected,
    )


def roc_auc(scores: np.ndarray, labels: np.ndarray) -> float:
    """ROC-AUC of ``scores`` (higher = more likely positive) against boolean ``labels``.

    Ties count one half (Mann-Whitney U). Non-finite scores are treated as the highest score
    (an unverifiable frame is flagged). Raises ValueError if only one class is present.
    """
    scores = np.asarray(scores, dtype=np.float64).reshape(-1)
    labels = np.asarray(labels, dtype=bool).reshape(-1)
    check_shape("labels", labels, (len(scores),))
    pos, neg = scores[labels], scores[~labels]
    if len(pos) == 0 or len(neg) == 0:
        raise ValueError("roc_auc needs both positive and negative labels")
    big = np.nanmax(np.where(np.isfinite(scores), scores, -np.inf))
    big = (big if np.isfinite(big) else 0.0) + 1.0
    pos = np.where(np.isfinite(pos), pos, big)
    neg = np.where(np.isfinite(neg), neg, big)
    greater = (pos[:, None] > neg[None, :]).sum()
    ties = (pos[:, None] == neg[None, :]).sum()
    return float((greater + 0.5 * ties) / (len(pos) * len(neg)))
