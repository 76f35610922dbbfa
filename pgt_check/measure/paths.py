"""In-process results of one frame's paths (with their arrays), the panel-image holder, and
the absolute evidence a frame adds to the run-level checks."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from pgt_check.enhance.base import Evidence
from pgt_check.measure.record import AbsoluteEvidence, PathMeasurement
from pgt_check.types import Camera


@dataclass(frozen=True)
class PathImages:
    """Matches of one path for report panels: (N, 2) working pixels, (N,) bool inliers and the
    photo_from_render homography in working pixels (None when it failed)."""

    kpts_render: np.ndarray
    kpts_photo: np.ndarray
    inliers: np.ndarray
    photo_from_render: np.ndarray | None = None


@dataclass
class FrameImages:
    """Working-resolution images and matches of one frame, filled on request for report panels.

    photo / render / enhanced: (h, w, 3) float32 RGB [0, 1]; kpts_*: (N, 2) working pixels;
    inliers: (N,) bool of the homography of the deciding path. ``paths`` holds the matches of
    each path that ran ("raw", "enhanced") with its homography in working pixels.
    """

    photo: np.ndarray | None = None
    render: np.ndarray | None = None
    enhanced: np.ndarray | None = None
    kpts_render: np.ndarray | None = None
    kpts_photo: np.ndarray | None = None
    inliers: np.ndarray | None = None
    paths: dict[str, PathImages] = field(default_factory=dict)


@dataclass(frozen=True, eq=False)
class PathResult:
    """Matching + homography of one image against the photo, with its arrays (in-process only).

    ``photo_from_render`` is in original photo pixels; keypoints in working pixels.
    """

    n_matches: int
    n_inliers: int
    inlier_ratio: float
    reason: str  # homography failure reason, "" on success
    photo_from_render: np.ndarray | None
    corner_error_px: float | None
    kpts_render: np.ndarray
    kpts_photo: np.ndarray
    inliers: np.ndarray
    n_kpts_render: int
    n_kpts_photo: int
    t_match_s: float
    t_homography_s: float

    @property
    def success(self) -> bool:
        return self.photo_from_render is not None

    def images(self, scale: tuple[float, float]) -> PathImages:
        """The matches for report panels, homography back in working pixels (``scale``: working
        / original size)."""
        from pgt_check.geometry.homography import scale_homography

        h = None
        if self.photo_from_render is not None:
            h = scale_homography(self.photo_from_render, 1.0 / scale[0], 1.0 / scale[1])
        return PathImages(self.kpts_render, self.kpts_photo, self.inliers, h)

    def measurement(
        self,
        kind: str,
        method: str,
        evidence: Evidence,
        camera: Camera,
        reference_id: str | None = None,
    ) -> PathMeasurement:
        """The stored (JSON-able) part of this result; shifts in ``camera``'s pixels."""
        from pgt_check.geometry.homography import corner_shift_and_zoom

        h = dx = dy = zoom = None
        if self.success:
            assert self.photo_from_render is not None
            h = tuple(tuple(map(float, r)) for r in self.photo_from_render)
            dx, dy, zoom = corner_shift_and_zoom(
                self.photo_from_render, camera.width, camera.height
            )
        return PathMeasurement(
            kind=kind,
            method=method,
            evidence=evidence,
            n_kpts_render=self.n_kpts_render,
            n_kpts_photo=self.n_kpts_photo,
            n_matches=self.n_matches,
            n_inliers=self.n_inliers,
            inlier_ratio=self.inlier_ratio,
            reason=self.reason,
            photo_from_render=h,
            corner_error_px=self.corner_error_px,
            shift_dx_px=dx,
            shift_dy_px=dy,
            zoom=zoom,
            reference_id=reference_id,
        )


#: correspondences a frame keeps for the run-level checks (deterministic subsample)
MAX_EVIDENCE_POINTS = 200


def absolute_evidence(
    paths: Sequence[tuple[PathResult, str]],
    depth: np.ndarray,
    cam_w: Camera,
    scale: tuple[float, float],
    max_points: int = MAX_EVIDENCE_POINTS,
    extra: Sequence[tuple[np.ndarray, np.ndarray, str]] = (),
) -> AbsoluteEvidence | None:
    """Homography inliers of absolute paths as 2D-3D correspondences (None if there are none).

    Render keypoints are lifted with the render depth into the checked camera's frame
    (``geometry.pnp.lift_keypoints``: depth-edge keypoints are dropped); photo keypoints are
    scaled from working to original pixels. ``extra``: correspondences lifted elsewhere
    (pts2d, pts_cam, source). At most ``max_points`` per source are kept (evenly spaced).
    """
    from pgt_check.geometry.pnp import lift_keypoints

    pts2d, pts_cam, sources = [], [], []
    for path, source in paths:
        if not path.success or not len(path.inliers):
            continue
        kr, kp = path.kpts_render[path.inliers], path.kpts_photo[path.inliers]
        valid, xyz = lift_keypoints(kr, depth, cam_w, np.eye(4))
        if not valid.any():
            continue
        orig, xyz = (kp[valid] + 0.5) / np.asarray(scale) - 0.5, xyz[valid]
        if len(orig) > max_points:
            keep = np.linspace(0, len(orig) - 1, max_points).round().astype(int)
            orig, xyz = orig[keep], xyz[keep]
        pts2d.append(orig)
        pts_cam.append(xyz)
        sources.append(source)
    for p2d, p3d, source in extra:  # e.g. matched geometric edges (already lifted)
        if len(p2d):
            pts2d.append(p2d)
            pts_cam.append(p3d)
            sources.append(source)
    counts = tuple(len(p) for p in pts2d)
    if not pts2d:
        return None
    p2, p3 = np.concatenate(pts2d), np.concatenate(pts_cam)
    return AbsoluteEvidence(
        tuple(sources),
        tuple((float(u), float(v)) for u, v in p2),
        tuple((float(x), float(y), float(z)) for x, y, z in p3),
        counts,
    )
