"""Parts of one frame's measurement that hold no checker state: the per-frame stage clock,
the frame at working resolution, the enhance decision, the reason of each input error, the
reference choice per frame and the formatting of internal errors. Used by
``pgt_check.measure.checker.FrameChecker`` (and the executors: ``format_exception``).
"""

from __future__ import annotations

import logging
import time
import traceback
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np

from pgt_check.config import (
    EdgeConfig,
    EnhanceConfig,
    HomographyConfig,
    InputConfig,
    MatchConfig,
    PoseConfig,
    RenderConfig,
    VerdictConfig,
)
from pgt_check.constants import EDGES_DECISIVE_SUPPORT
from pgt_check.errors import ImageSizeMismatchError, PixelCapError, ReferenceUnreadableError
from pgt_check.measure.paths import PathResult
from pgt_check.measure.record import (
    EnhanceWhy,
    FrameMeasurement,
    MeasureReason,
    PoseEstimate,
    Timings,
)
from pgt_check.types import Camera, Frame, Trajectory

logger = logging.getLogger(__name__)


class MeasuringConfig(Protocol):
    """What the measure stage reads of the settings (``FrameChecker``, ``pick_references``):
    the measurement sections, the verdict's coverage and threshold (the auto-enhance decision),
    ``fail_fast`` and the threads per process; never the gate, the run-level checks, the
    corrections or the outputs. ``RunConfig`` has them; a type checker refuses more."""

    @property
    def input(self) -> InputConfig: ...
    @property
    def render(self) -> RenderConfig: ...
    @property
    def match(self) -> MatchConfig: ...
    @property
    def homography(self) -> HomographyConfig: ...
    @property
    def enhance(self) -> EnhanceConfig: ...
    @property
    def edges(self) -> EdgeConfig: ...
    @property
    def pose(self) -> PoseConfig: ...
    @property
    def verdict(self) -> VerdictConfig: ...
    @property
    def fail_fast(self) -> bool: ...
    @property
    def threads(self) -> int | None: ...


#: reasons for which the enhanced path runs / does not run
ENHANCE = (
    EnhanceWhy.MODE_ALWAYS,
    EnhanceWhy.RAW_FAILED,
    EnhanceWhy.RAW_FEW_INLIERS,
    EnhanceWhy.RAW_NEAR_THRESHOLD,
)
NO_ENHANCE = (
    EnhanceWhy.MODE_NEVER,
    EnhanceWhy.RAW_DECISIVE,
    EnhanceWhy.NO_REFERENCE,
    EnhanceWhy.EDGES_DECISIVE,
)



def below_band(corner_error_px: float, threshold: float, e: EnhanceConfig) -> bool:
    """A corner error below the ``auto_margin`` band around the threshold: a clear PASS."""
    return corner_error_px < (1.0 - e.auto_margin) * threshold


def edges_decisive(path: Any, threshold: float, enhance_cfg: Any) -> bool:
    """The edge path (a ``PathMeasurement``) gives a clear PASS: aligned, not ambiguous, well
    supported, and its corner error below the ``auto_margin`` band around the threshold (the
    band that makes the raw path not decisive). A clear FAIL still runs the enhanced path: its
    PnP estimate is what corrects the pose where the raw render cannot be matched."""
    if not path.success or path.corner_error_px is None:
        return False
    if path.inlier_ratio < EDGES_DECISIVE_SUPPORT:
        return False
    return below_band(path.corner_error_px, threshold, enhance_cfg)


def raw_contradicts(raw: PathResult, threshold: float, e: EnhanceConfig) -> bool:
    """The raw path aligned but is not itself a clear PASS (corner error at or above the
    ``auto_margin`` band's lower edge): it does not back a clear edge PASS. Two absolute paths
    that disagree then get the enhanced path as a third witness instead of a verdict that rests
    on whichever of the two the judging trusts more (on blurred TSDF textures a raw render
    with a few dozen inliers and the edges each failed correct frames or passed wrong ones:
    reports/scenes_loso.md, tenth session)."""
    return (
        raw.success
        and raw.corner_error_px is not None
        and not below_band(raw.corner_error_px, threshold, e)
    )


def clear_pass(path: PathResult, threshold: float, e: EnhanceConfig) -> bool:
    """A feature path's clear PASS: aligned with at least ``auto_min_inliers`` inliers and its
    corner error below the ``auto_margin`` band around the threshold (the band in which a
    result is not decisive, ``enhance_decision``)."""
    return (
        path.success
        and path.n_inliers >= e.auto_min_inliers
        and path.corner_error_px is not None
        and below_band(path.corner_error_px, threshold, e)
    )


@dataclass(frozen=True, eq=False)
class Working:
    """One frame at working resolution: photo, cameras (original and working), the size and
    scale (working / original), the render, and (for paths that work at another size) the
    photo at its original size and the checked pose."""

    photo: np.ndarray
    camera: Camera
    cam_w: Camera
    size: tuple[int, int]
    scale: tuple[float, float]
    render: Any
    original: np.ndarray
    world_from_cam: np.ndarray


@dataclass
class Clock:
    """Accumulates seconds per stage of one frame."""

    spent: dict[str, float] = field(default_factory=dict)

    def add(self, stage: str, seconds: float) -> None:
        self.spent[stage] = self.spent.get(stage, 0.0) + seconds

    def timings(self, total: float) -> Timings:
        return Timings(**self.spent, total=total)


def enhance_decision(raw: PathResult, threshold: float, e: EnhanceConfig) -> tuple[EnhanceWhy, str]:
    """Why the enhanced path runs or not for this raw result (``enhance.mode`` and, in auto
    mode, whether the raw result is decisive)."""
    if e.mode == "never":
        return EnhanceWhy.MODE_NEVER, ""
    if e.mode == "always":
        return EnhanceWhy.MODE_ALWAYS, ""
    if not raw.success:
        return EnhanceWhy.RAW_FAILED, raw.reason
    if raw.n_inliers < e.auto_min_inliers:
        return EnhanceWhy.RAW_FEW_INLIERS, ""
    assert raw.corner_error_px is not None  # a successful path has one
    if abs(raw.corner_error_px - threshold) <= e.auto_margin * threshold:
        return EnhanceWhy.RAW_NEAR_THRESHOLD, ""
    return EnhanceWhy.RAW_DECISIVE, ""


#: per-frame reasons of the specific input errors (any other InputError: image_unreadable)
INPUT_ERROR_REASONS: dict[type, MeasureReason] = {
    ImageSizeMismatchError: MeasureReason.IMAGE_SIZE_MISMATCH,
    PixelCapError: MeasureReason.PIXEL_CAP_EXCEEDED,
    ReferenceUnreadableError: MeasureReason.REFERENCE_UNREADABLE,
}


def replace_measurement(m: FrameMeasurement, **changes: Any) -> FrameMeasurement:
    from dataclasses import replace

    return replace(m, **changes)


def format_exception(err: BaseException) -> str:
    """The last 2000 characters of a traceback (stored as an internal error's detail)."""
    return "".join(traceback.format_exception(err))[-2000:]


def pick_references(
    traj: Trajectory, frames: Sequence[Frame], config: MeasuringConfig
) -> dict[str, tuple[Frame, ...]]:
    """Reference frames per checked frame, best first (any frame of the trajectory may serve)."""
    if config.enhance.mode == "never":
        return {}
    from pgt_check.enhance.reference import select_references

    choices = select_references(
        traj.frames, config.enhance.reference, only=[f.frame_id for f in frames]
    )
    by_id = traj.by_id()
    refs = {f.frame_id: tuple(by_id[i] for i in choices[f.frame_id].frame_ids) for f in frames}
    missing = sum(not r for r in refs.values())
    if missing:
        logger.warning(
            "%d of %d frames have no usable reference and are checked raw only",
            missing,
            len(frames),
        )
    return refs


def match_path(
    matcher: Any,
    homography: HomographyConfig,
    image: np.ndarray,
    photo_w: np.ndarray,
    mask: np.ndarray | None,
    size: tuple[int, int],
    scale: tuple[float, float],
    camera: Camera,
    clock: Clock,
    detail_short_side: int | None = None,
) -> PathResult:
    """Match ``image`` (render or enhanced, working size) to the photo and fit the homography;
    the homography and corner error in original photo pixels, keypoints in working pixels.

    ``detail_short_side``: ``image`` carries detail only up to this short side (an enhancement
    made at that size and resized up, where a detector finds few repeatable keypoints:
    reports/mariner_absolute.md); both images are then matched at that size."""
    w, h = size
    if detail_short_side is not None and detail_short_side < min(w, h):
        return _match_smaller(matcher, homography, image, photo_w, mask, size, scale, camera,
                              clock, detail_short_side / min(w, h))
    from pgt_check.geometry.homography import (
        corner_error,
        estimate_homography,
        scale_homography,
    )

    t = time.perf_counter()
    matches = matcher.match(image, photo_w, mask0=mask)
    t_match = time.perf_counter() - t
    t = time.perf_counter()
    res = estimate_homography(
        matches.kpts0, matches.kpts1, size[0], size[1], homography
    )
    t_h = time.perf_counter() - t
    clock.add("match", t_match)
    clock.add("homography", t_h)
    photo_from_render: np.ndarray | None = None
    err: float | None = None
    if res.success:
        assert res.photo_from_render is not None  # a successful estimate has one
        photo_from_render = scale_homography(res.photo_from_render, *scale)
        err = corner_error(photo_from_render, camera.width, camera.height)
    n = len(matches)
    return PathResult(
        n,
        res.n_inliers,
        res.n_inliers / n if n else 0.0,
        "" if res.success or res.reason is None else res.reason.value,
        photo_from_render,
        err,
        matches.kpts0,
        matches.kpts1,
        res.inliers,
        matches.n_kpts0,
        matches.n_kpts1,
        t_match,
        t_h,
    )


def _match_smaller(
    matcher: Any, homography: HomographyConfig, image: np.ndarray, photo_w: np.ndarray,
    mask: np.ndarray | None, size: tuple[int, int], scale: tuple[float, float], camera: Camera,
    clock: Clock, f: float,
) -> PathResult:
    """``match_path`` with both images (and the mask) resized by ``f`` < 1; keypoints back in
    working pixels."""
    from dataclasses import replace

    import cv2

    small = (max(1, round(size[0] * f)), max(1, round(size[1] * f)))
    fx, fy = small[0] / size[0], small[1] / size[1]
    image_s, photo_s = (cv2.resize(a, small, interpolation=cv2.INTER_AREA)
                        for a in (image, photo_w))
    if mask is not None:
        mask = cv2.resize(mask.astype(np.uint8), small, interpolation=cv2.INTER_NEAREST) > 0
    res = match_path(matcher, homography, image_s, photo_s, mask, small,
                     (scale[0] * fx, scale[1] * fy), camera, clock)
    up = np.array([1.0 / fx, 1.0 / fy])
    return replace(res, kpts_render=np.asarray(res.kpts_render) * up,
                   kpts_photo=np.asarray(res.kpts_photo) * up)


def pose_estimate(
    path: PathResult, depth: np.ndarray, cam_w: Camera, frame: Frame, p: PoseConfig, clock: Clock
) -> PoseEstimate:
    """The PnP pose correction from a path's matches and the render depth (``pose`` settings)."""
    from pgt_check.geometry.pnp import estimate_pose_correction

    t = time.perf_counter()
    corr = estimate_pose_correction(
        path.kpts_render,
        path.kpts_photo,
        depth,
        cam_w,
        frame.world_from_cam,
        max_error_px=p.max_error_px,
        min_inliers=p.min_inliers,
    )
    clock.add("pose", time.perf_counter() - t)
    if not corr.success or corr.world_from_cam is None:
        return PoseEstimate(corr.n_inliers, "" if corr.reason is None else corr.reason.value)
    return PoseEstimate(
        corr.n_inliers,
        "",
        corr.dt,
        corr.drot_deg,
        tuple(tuple(map(float, r)) for r in corr.world_from_cam),
    )
