"""Pose-error estimate: render keypoints lifted to 3D with the render depth, PnP against the photo.

The correction is reported as the difference between the checked pose and the PnP pose:
camera-centre distance (scene units) and rotation angle (degrees), with the PnP inlier count.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from enum import Enum

import numpy as np

from pgt_check.geometry.transforms import apply_rigid, invert_rigid, make_rigid, pose_difference
from pgt_check.types import Camera, check_shape

logger = logging.getLogger(__name__)


class PoseReason(str, Enum):
    """Why the PnP estimate failed (machine-readable, closed set)."""

    TOO_FEW_3D_POINTS = "too_few_3d_points"
    PNP_FAILED = "pnp_failed"
    TOO_FEW_PNP_INLIERS = "too_few_pnp_inliers"


@dataclass(frozen=True, eq=False)
class PoseCorrection:
    success: bool
    reason: PoseReason | None  # None on success
    dt: float | None = None
    drot_deg: float | None = None
    n_inliers: int = 0
    world_from_cam: np.ndarray | None = None  # the PnP estimate


def lift_keypoints(
    kpts: np.ndarray, depth: np.ndarray, camera: Camera, world_from_cam: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Back-project (N, 2) render pixels with the render depth (nearest pixel).

    Returns (valid (N,) bool, points_world (N, 3) float64; rows of invalid points are NaN).
    A keypoint is valid where the depth is positive and agrees within 5 % with its 3x3
    neighbourhood (keypoints on depth edges lift to the wrong surface).
    """
    kpts = np.asarray(kpts, dtype=np.float64)
    check_shape("kpts", kpts, (None, 2))
    h, w = depth.shape
    ui = np.clip(np.round(kpts[:, 0]).astype(int), 0, w - 1)
    vi = np.clip(np.round(kpts[:, 1]).astype(int), 0, h - 1)
    z = depth[vi, ui].astype(np.float64)
    valid = z > 0
    for du in (-1, 0, 1):
        for dv in (-1, 0, 1):
            zn = depth[np.clip(vi + dv, 0, h - 1), np.clip(ui + du, 0, w - 1)]
            valid &= np.abs(zn - z) <= 0.05 * np.maximum(z, 1e-12)
    fx, fy = camera.focal
    cx, cy = camera.principal_point
    pts_cam = np.stack([(kpts[:, 0] - cx) / fx * z, (kpts[:, 1] - cy) / fy * z, z], axis=1)
    pts = apply_rigid(np.asarray(world_from_cam, np.float64), pts_cam)
    pts[~valid] = np.nan
    return valid, pts


def estimate_pose_correction(
    kpts_render: np.ndarray,
    kpts_photo: np.ndarray,
    depth: np.ndarray,
    camera: Camera,
    world_from_cam: np.ndarray,
    max_error_px: float = 4.0,
    min_inliers: int = 12,
) -> PoseCorrection:
    """PnP + LO-RANSAC (pycolmap) of the photo's pose from lifted render keypoints.

    kpts_render, kpts_photo: (N, 2) matched pixels of the render and the photo, both in the
    pixels of ``camera`` (the working camera the render was made with); depth: (h, w) render
    depth. Points are expressed relative to the checked camera centre before PnP (float64,
    so georeferenced coordinates lose nothing).
    """
    kpts_render = np.asarray(kpts_render, np.float64).reshape(-1, 2)
    kpts_photo = np.asarray(kpts_photo, np.float64).reshape(-1, 2)
    check_shape("kpts_photo", kpts_photo, (len(kpts_render), 2))
    valid, pts = lift_keypoints(kpts_render, depth, camera, world_from_cam)
    return estimate_pose_from_points(
        pts[valid], kpts_photo[valid], camera, world_from_cam, max_error_px, min_inliers
    )


def estimate_pose_from_points(
    points_world: np.ndarray,
    kpts_photo: np.ndarray,
    camera: Camera,
    world_from_cam: np.ndarray,
    max_error_px: float = 4.0,
    min_inliers: int = 12,
) -> PoseCorrection:
    """PnP + LO-RANSAC (pycolmap) of the photo's pose from (N, 3) world points and their (N, 2)
    photo pixels (pixels of ``camera``). ``world_from_cam``: the pose the correction is
    reported against; the points are expressed relative to its centre before PnP."""
    import pycolmap

    pts = np.asarray(points_world, np.float64).reshape(-1, 3)
    kpts_photo = np.asarray(kpts_photo, np.float64).reshape(-1, 2)
    check_shape("kpts_photo", kpts_photo, (len(pts), 2))
    if len(pts) < max(4, min_inliers):
        return PoseCorrection(False, PoseReason.TOO_FEW_3D_POINTS, n_inliers=0)
    origin = np.asarray(world_from_cam, np.float64)[:3, 3]
    local = pts - origin
    # COLMAP pixel convention: add 0.5 to OpenCV pixel coordinates and principal point
    fx, fy = camera.focal
    cx, cy = camera.principal_point
    cam = pycolmap.Camera(
        model="PINHOLE", width=camera.width, height=camera.height,
        params=[fx, fy, cx + 0.5, cy + 0.5],
    )
    opts = pycolmap.AbsolutePoseEstimationOptions()
    opts.ransac.max_error = max_error_px
    opts.ransac.random_seed = 0  # deterministic: the same frame gives the same estimate anywhere
    try:
        res = pycolmap.estimate_and_refine_absolute_pose(kpts_photo + 0.5, local, cam, opts)
    except Exception as err:  # pycolmap raises plain RuntimeError/ValueError on degenerate input
        logger.debug("PnP failed: %s", err)
        res = None
    if res is None:
        return PoseCorrection(False, PoseReason.PNP_FAILED)
    n_inl = int(np.sum(res["inlier_mask"]))
    if n_inl < min_inliers:
        return PoseCorrection(False, PoseReason.TOO_FEW_PNP_INLIERS, n_inliers=n_inl)
    cfw = res["cam_from_world"]
    mat = cfw.matrix() if callable(getattr(cfw, "matrix", None)) else np.asarray(cfw.matrix)
    cam_from_local = np.vstack([np.asarray(mat, np.float64), [0, 0, 0, 1]])
    local_from_cam = invert_rigid(cam_from_local)
    world_from_cam_est = make_rigid(local_from_cam[:3, :3], local_from_cam[:3, 3] + origin)
    dt, dr = pose_difference(np.asarray(world_from_cam, np.float64), world_from_cam_est)
    return PoseCorrection(True, None, dt, dr, n_inl, world_from_cam_est)
