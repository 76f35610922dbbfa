"""A camera's estimated calibration error, and removing it (``--remove-calibration``,
``--calibration-from``).

The error is ``true_cam_from_checked_cam``: a rotation (principal-point shift + roll), a focal
scale and, where it was fitted, a camera-frame translation (a camera beside the sensor whose
poses are given). A rotation and a zoom move every pixel the same way whatever the depth (a
homography); a translation moves near points more than far ones, so removing it needs the
depth: exactly per evidence point (its 3D point is known), and per frame as the homography
induced at the frame's median depth.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from pgt_check.errors import InputError

logger = logging.getLogger(__name__)


def camera_matrix(intrinsics: Sequence[float], focal_scale: float = 1.0) -> np.ndarray:
    """(3, 3) K of pinhole ``intrinsics`` (fx, fy, cx, cy), focal lengths scaled."""
    fx, fy, cx, cy = intrinsics
    return np.array([[fx * focal_scale, 0, cx], [0, fy * focal_scale, cy], [0, 0, 1]], float)


@dataclass(frozen=True, eq=False)
class CameraCalibration:
    """rotation (3, 3), focal_scale, translation (3,) of ``true_cam_from_checked_cam``;
    ``separable``: false when the run that estimated it could not tell it from its own
    registration (``separable_from_registration``), so it may carry that run's own
    misregistration (a trusted run covering part of a sweep: reports/trusted_subsets.md);
    ``tolerance_px``: that run's shared-error threshold (how well a run's registration is
    known when it passes, or when the user asserts it; nan where the summary has none);
    ``views``: (N, 6) the camera centres and optical axes it was estimated on (None where the
    summary has none)."""

    rotation: np.ndarray
    focal_scale: float
    translation: np.ndarray
    separable: bool = True
    tolerance_px: float = math.nan
    views: np.ndarray | None = None

    @classmethod
    def from_estimate(cls, est: Any) -> CameraCalibration | None:
        """From a ``CalibrationEstimate`` (None when it failed)."""
        if not est.success or est.rotation is None or not math.isfinite(est.focal_scale):
            return None
        t = getattr(est, "translation", None)
        return cls(np.asarray(est.rotation, float), float(est.focal_scale), _vec3(t))

    def homography(self, intrinsics: Sequence[float], depth: float | None = None) -> np.ndarray:
        """(3, 3) photo_from_render: K_zoom (R + t n^T / depth) K^-1, the map this error
        induces for a fronto-parallel plane at ``depth`` (exact for R and zoom; the
        translation's part needs a depth and is left out without one)."""
        m = self.rotation.copy()
        if depth is not None and math.isfinite(depth) and depth > 0:
            m[:, 2] += self.translation / depth
        h = camera_matrix(intrinsics, self.focal_scale) @ m @ np.linalg.inv(camera_matrix(intrinsics))
        return h / h[2, 2]

    def remove(self, e: Any) -> Any:
        """The frame's evidence (``FrameEvidence``) with this error taken out of its photo
        points, point by point (each point's depth is known)."""
        r, c = e.world_from_cam[:3, :3], e.world_from_cam[:3, 3]
        xc = (e.pts3d - c) @ r
        xt = xc @ self.rotation.T + self.translation
        k0 = e.K
        kz = k0.copy()
        kz[0, 0] *= self.focal_scale
        kz[1, 1] *= self.focal_scale
        kz[0, 1] *= self.focal_scale
        with np.errstate(divide="ignore", invalid="ignore"):
            u0 = (xc @ k0.T)[:, :2] / xc[:, 2:3]
            u1 = (xt @ kz.T)[:, :2] / xt[:, 2:3]
        delta = np.where(np.isfinite(u1 - u0), u1 - u0, 0.0)
        return replace(e, pts2d=e.pts2d - delta)


def _vec3(t: Any) -> np.ndarray:
    v = np.zeros(3) if t is None else np.asarray(t, float).reshape(-1)
    if v.shape != (3,) or not np.all(np.isfinite(v)):
        return np.zeros(3)
    return v


def views_of(poses: Sequence[np.ndarray]) -> np.ndarray:
    """(N, 6) camera centre and optical axis (world) of ``world_from_cam`` poses (4x4)."""
    if not len(poses):
        return np.zeros((0, 6))
    p = np.asarray(poses, np.float64)
    if p.ndim != 3 or p.shape[1:] != (4, 4):
        raise ValueError(f"poses: expected (N, 4, 4) world_from_cam; got {p.shape}")
    return np.concatenate([p[:, :3, 3], p[:, :3, 2]], axis=1)


def uncovered_share(trusted: np.ndarray | None, views: np.ndarray, depth: float) -> float:
    """The share of ``views`` (N, 6) that a trusted run's views (M, 6; ``views_of``) do not
    cover: farther from every trusted view than the trusted views are from each other (the
    largest gap between a trusted view and its nearest neighbour). The distance of two views
    is their centres' distance over the scene ``depth`` plus the angle (rad) between their
    axes. A trusted run spread along a sweep covers held-out frames of it; one on a segment
    leaves ~3/4 of them out (reports/trusted_subsets.md). None (a summary without views): 0,
    as before views were recorded."""
    if trusted is None or not len(views):
        return 0.0
    if trusted.ndim != 2 or trusted.shape[1] != 6 or views.ndim != 2 or views.shape[1] != 6:
        raise ValueError(f"views: expected (M, 6) and (N, 6); got {trusted.shape}, {views.shape}")
    if not (math.isfinite(depth) and depth > 0):
        raise ValueError(f"depth: expected a positive number; got {depth}")

    radius = (float(_nearest_view(trusted, trusted, depth, skip_self=True).max())
              if len(trusted) > 1 else 0.0)
    return float(np.mean(_nearest_view(views, trusted, depth) > radius))


def _nearest_view(a: np.ndarray, b: np.ndarray, depth: float, *, skip_self: bool = False,
                  rows: int = 256) -> np.ndarray:
    """(len(a),) distance of each view of ``a`` to its nearest in ``b`` (``uncovered_share``'s
    distance; ``skip_self``: ``a`` is ``b`` and a view is not its own neighbour), ``rows`` views
    of ``a`` at a time so that long runs (thousands of frames) never hold an (N, M, 3) array."""
    ub = b[:, 3:] / np.linalg.norm(b[:, 3:], axis=1, keepdims=True)
    out = np.empty(len(a))
    for i in range(0, len(a), rows):
        blk = a[i:i + rows]
        ua = blk[:, 3:] / np.linalg.norm(blk[:, 3:], axis=1, keepdims=True)
        d = (np.linalg.norm(blk[:, None, :3] - b[None, :, :3], axis=2) / depth
             + np.arccos(np.clip(ua @ ub.T, -1.0, 1.0)))
        if skip_self:
            d[np.arange(len(blk)), np.arange(i, i + len(blk))] = np.inf
        out[i:i + rows] = d.min(axis=1)
    return out


def frame_depths(evidence: Sequence[Any]) -> dict[str, float]:
    """Frame id -> the median depth of its evidence points (frames with none left out)."""
    depth = {}
    for e in evidence:
        z = (e.pts3d - e.world_from_cam[:3, 3]) @ e.world_from_cam[:3, 2]
        z = z[np.isfinite(z) & (z > 0)]
        if len(z):
            depth[e.frame_id] = float(np.median(z))
    return depth


def frame_homographies(
    cals: Mapping[str, CameraCalibration],
    evidence: Sequence[Any],
    intrinsics: Mapping[str, Sequence[float]],
    cameras: Mapping[str, str],
) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]]:
    """(per camera, per frame) photo_from_render of the calibration error: per frame at the
    median depth of its evidence, per camera at the median over its frames (for frames
    without evidence). ``cameras``: frame id -> camera id of every frame."""
    depth = frame_depths(evidence)
    per_cam, per_frame = {}, {}
    for cam_id, cal in cals.items():
        if cam_id not in intrinsics:
            continue
        frames = [f for f, c in cameras.items() if c == cam_id]
        zs = [depth[f] for f in frames if f in depth]
        per_cam[cam_id] = cal.homography(intrinsics[cam_id], np.median(zs) if zs else None)
        if np.any(cal.translation):
            for f in frames:
                if f in depth:
                    per_frame[f] = cal.homography(intrinsics[cam_id], depth[f])
    return per_cam, per_frame


def _trusted_entry(
    path: str, cam_id: str, entry: Any, tolerance_px: float = math.nan
) -> CameraCalibration | None:
    """One camera's entry of a trusted summary, checked strictly (InputError naming the field):
    None when it carries no estimate (rotation and focal scale both null or absent).
    ``tolerance_px``: the trusted run's shared threshold (``CameraCalibration.tolerance_px``)."""
    where = f"{path}: shared_errors.calibration[{cam_id!r}]"
    if not isinstance(entry, Mapping):
        raise InputError(f"{where}: expected a table; got {type(entry).__name__}")
    rot, scale, trans = entry.get("rotation"), entry.get("focal_scale"), entry.get("translation")
    if rot is None and scale is None:
        return None
    try:
        r = np.asarray(rot, dtype=np.float64)
    except (TypeError, ValueError):
        r = np.zeros(0)
    if r.shape != (3, 3) or not np.all(np.isfinite(r)):
        raise InputError(f"{where}.rotation: expected a finite 3x3 matrix; got {rot!r:.80}")
    if not np.allclose(r @ r.T, np.eye(3), atol=1e-6) or np.linalg.det(r) <= 0:
        raise InputError(f"{where}.rotation: expected a rotation matrix (orthonormal, det +1)")
    if isinstance(scale, bool) or not isinstance(scale, (int, float)) or not (
        math.isfinite(scale) and scale > 0
    ):
        raise InputError(f"{where}.focal_scale: expected a positive finite number; got {scale!r}")
    t = np.zeros(3)
    if trans is not None:
        try:
            t = np.asarray(trans, dtype=np.float64).reshape(-1)
        except (TypeError, ValueError):
            t = np.zeros(0)
        if t.shape != (3,) or not np.all(np.isfinite(t)):
            raise InputError(f"{where}.translation: expected 3 finite numbers; got {trans!r:.80}")
    separable = entry.get("separable_from_registration") is not False
    views = entry.get("views")
    if views is not None:
        try:
            views = np.asarray(views, dtype=np.float64)
        except (TypeError, ValueError):
            views = np.zeros(0)
        if (views.ndim != 2 or views.shape[1] != 6 or not np.all(np.isfinite(views))
                or not np.all(np.linalg.norm(views[:, 3:], axis=1) > 0)):
            raise InputError(f"{where}.views: expected rows of 6 finite numbers (camera centre "
                             "and a non-zero optical axis)")
    return CameraCalibration(r, float(scale), t, separable, tolerance_px, views)


def load_trusted_calibrations(path: str) -> dict[str, CameraCalibration]:
    """Every usable per-camera calibration of a trusted run's summary.json
    (``shared_errors.calibration``), each entry checked: InputError for a file that is missing,
    special, oversized or not JSON, a section of the wrong shape, a malformed estimate (a
    rotation that is not 3x3 orthonormal, a focal scale that is not a positive number,
    non-finite values) or no usable estimate at all."""
    from pgt_check.common.files import MAX_SMALL_JSON_BYTES, load_json_limited

    try:
        doc = load_json_limited(path, MAX_SMALL_JSON_BYTES, "--calibration-from summary")
    except InputError as err:
        raise InputError(f"--calibration-from: {err}") from None
    shared = doc.get("shared_errors") if isinstance(doc, dict) else None
    se = shared.get("calibration") if isinstance(shared, dict) else None
    if not isinstance(se, dict):
        raise InputError(
            f"{path}: expected the summary.json of a pgt-check run with a table "
            "shared_errors.calibration (--calibration-from)"
        )
    thr = shared.get("threshold_px") if isinstance(shared, dict) else None
    tolerance = (float(thr) if isinstance(thr, (int, float)) and not isinstance(thr, bool)
                 and math.isfinite(thr) and thr > 0 else math.nan)  # older summaries: none
    usable = {}
    for c, e in se.items():
        cal = _trusted_entry(path, str(c), e, tolerance)
        if cal is not None:
            usable[str(c)] = cal
    if not usable:
        raise InputError(f"{path}: no camera has a calibration estimate (--calibration-from)")
    return usable


def trusted_calibration(path: str, camera_ids: Sequence[str]) -> dict[str, CameraCalibration]:
    """Calibration errors per camera from a trusted run's summary.json
    (``shared_errors.calibration``), for this run's cameras (``--calibration-from``)."""
    usable = load_trusted_calibrations(path)
    out = {}
    for cam_id in camera_ids:
        cal = usable.get(cam_id)
        if cal is None and len(usable) == 1 and len(camera_ids) == 1:
            # one camera on both sides whose parameters changed (e.g. re-calibrated intrinsics)
            ((other, cal),) = usable.items()
            logger.warning(
                "--calibration-from: camera %r not in %s; using its only camera %r",
                cam_id,
                path,
                other,
            )
        if cal is None:
            raise InputError(f"{path}: no calibration estimate for camera {cam_id!r} "
                             f"(--calibration-from; it has {', '.join(map(repr, usable))})")
        out[cam_id] = cal
    return out
