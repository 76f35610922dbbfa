"""Pose corrections: iterate render -> match -> PnP from a frame's PnP estimate.

The measurement's PnP pose (``FrameMeasurement.pose``) is computed once, from the deciding path,
which may be the enhanced one (a render painted with a *reference* photo, whose own pose error
can bias it). ``refine_pose`` therefore uses it only as the starting point: every round renders
the mesh at the current pose and matches the **raw** render against the photo, lifts the render
keypoints with the render depth and solves PnP (pycolmap LO-RANSAC) for the next pose. So the
result rests on absolute evidence (mesh vs photo) only.

Uncertainty (``sigma_rot_deg``, ``sigma_t``): the root sum of squares of (a) the bootstrap
spread of the last round's PnP (correspondences resampled with replacement, RMS distance of the
bootstrap poses to the final one) and (b) the last round's update (how far from converged).
"""

from __future__ import annotations

import json
import logging
import math
from collections.abc import Iterable, Mapping
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path
from typing import Any

import numpy as np

from pgt_check.types import Frame

logger = logging.getLogger(__name__)

#: frames.csv / report columns added by the correction step (empty when it did not run)
CORRECTION_COLUMNS: tuple[str, ...] = (
    "corr_applied",
    "corr_drot_deg",
    "corr_dt",
    "corr_sigma_rot_deg",
    "corr_sigma_t",
    "corr_corner_error_px",
    "corr_rounds",
    "corr_start",
    "corr_reason",
)

#: file in the run directory that keeps the corrections (``pgt-check report`` reads it back)
CORRECTIONS_FILE = "corrections.json"


@dataclass(frozen=True)
class Correction:
    """The corrected pose of one frame (JSON-able; poses as nested lists).

    ``drot_deg`` / ``dt``: from the checked pose to the corrected one (degrees, scene units).
    ``corner_error_px_before``: the raw corner error at the start pose of the first round;
    ``corner_error_px``: the raw corner error of the render at the last round's start pose (the
    final update after it is part of the uncertainty). ``start``: "pnp_raw", "pnp_enhanced"
    (the measurement's PnP estimate and the path it came from) or "checked" (no estimate).
    ``depth``: median render depth (scene units), the scale for "1 % of scene depth".
    ``applied``: written to the corrected trajectory: success, corner_error_px <= the frame's
    threshold and sigma_rot_deg <= max(0.1 deg, half the correction) (else ``reason`` is
    "not_verified" or "uncertain").
    """

    frame_id: str
    success: bool
    reason: str = ""
    world_from_cam: tuple[tuple[float, ...], ...] | None = None
    drot_deg: float | None = None
    dt: float | None = None
    sigma_rot_deg: float | None = None
    sigma_t: float | None = None
    corner_error_px_before: float | None = None
    corner_error_px: float | None = None
    n_inliers: int = 0
    rounds: int = 0
    start: str = "checked"
    depth: float | None = None
    applied: bool = False
    steps: tuple[tuple[float, float], ...] = field(default_factory=tuple)

    @property
    def pose(self) -> np.ndarray | None:
        return None if self.world_from_cam is None else np.asarray(self.world_from_cam, float)

    def to_json(self) -> dict[str, Any]:
        d = asdict(self)
        return {k: _clean(v) for k, v in d.items()}

    @classmethod
    def from_json(cls, data: Mapping[str, Any]) -> Correction:
        names = {f.name for f in fields(cls)}
        d = {k: v for k, v in data.items() if k in names}
        if d.get("world_from_cam") is not None:
            d["world_from_cam"] = tuple(tuple(map(float, r)) for r in d["world_from_cam"])
        d["steps"] = tuple(tuple(s) for s in d.get("steps") or ())
        return cls(**d)

    def row(self) -> dict[str, Any]:
        """The ``CORRECTION_COLUMNS`` values of this correction."""
        return {
            "corr_applied": self.applied,
            "corr_drot_deg": self.drot_deg,
            "corr_dt": self.dt,
            "corr_sigma_rot_deg": self.sigma_rot_deg,
            "corr_sigma_t": self.sigma_t,
            "corr_corner_error_px": self.corner_error_px,
            "corr_rounds": self.rounds,
            "corr_start": self.start,
            "corr_reason": self.reason,
        }


def _clean(v: Any) -> Any:
    if isinstance(v, float) and not math.isfinite(v):
        return None
    if isinstance(v, (list, tuple)):
        return [_clean(x) for x in v]
    return v


def save_corrections(
    out_dir: str | Path, corrections: Iterable[Correction], fingerprint: str = ""
) -> Path:
    path = Path(out_dir) / CORRECTIONS_FILE
    doc = {"fingerprint": fingerprint, "corrections": [c.to_json() for c in corrections]}
    from pgt_check.files import atomic_write_text

    atomic_write_text(path, json.dumps(doc, indent=1) + "\n")
    return path


def load_corrections(out_dir: str | Path) -> dict[str, Correction]:
    """The corrections stored in a run directory by frame id ({} if there are none)."""
    path = Path(out_dir) / CORRECTIONS_FILE
    if not path.is_file():
        return {}
    try:
        doc = json.loads(path.read_text())
        return {str(d["frame_id"]): Correction.from_json(d) for d in doc.get("corrections", [])}
    except (ValueError, KeyError, TypeError) as err:
        logger.warning("%s unreadable, corrections left out: %s", path, err)
        return {}


@dataclass(frozen=True, eq=False)
class _Round:
    corner_error_px: float | None
    pose: np.ndarray | None  # PnP result (None on failure)
    reason: str
    n_inliers: int
    kpts_render: np.ndarray
    kpts_photo: np.ndarray
    depth: np.ndarray
    cam_w: Any


def _round(
    checker: Any,
    frame: Frame,
    pose: np.ndarray,
    photo_w: np.ndarray,
    camera: Any,
    size: tuple[int, int],
) -> _Round:
    """Render at ``pose``, match raw render vs photo, homography corner error, PnP."""
    from pgt_check.geometry.pnp import estimate_pose_correction
    from pgt_check.measure.steps import Clock, match_path

    cfg = checker.config
    scale = (size[0] / camera.width, size[1] / camera.height)
    cam_w = camera.scaled(*scale)
    render = checker.renderer.render(cam_w, pose)
    empty = np.zeros((0, 2))
    if render.coverage_fraction < cfg.verdict.min_coverage:
        return _Round(None, None, "low_coverage", 0, empty, empty, render.depth, cam_w)
    path = match_path(checker.matcher, cfg.homography, render.rgb, photo_w, render.coverage,
                      size, scale, camera, Clock())
    corr = estimate_pose_correction(
        path.kpts_render,
        path.kpts_photo,
        render.depth,
        cam_w,
        pose,
        max_error_px=cfg.pose.max_error_px,
        min_inliers=cfg.pose.min_inliers,
    )
    return _Round(
        path.corner_error_px,
        corr.world_from_cam if corr.success else None,
        "" if corr.success else corr.reason.value,
        corr.n_inliers,
        np.asarray(path.kpts_render),
        np.asarray(path.kpts_photo),
        render.depth,
        cam_w,
    )


def _bootstrap(
    rnd: _Round, start: np.ndarray, final: np.ndarray, n: int, seed: int, cfg: Any
) -> tuple[float, float]:
    """RMS (rotation deg, centre distance) of PnP on resampled correspondences vs ``final``."""
    from pgt_check.geometry.pnp import estimate_pose_correction
    from pgt_check.geometry.transforms import pose_difference

    m = len(rnd.kpts_render)
    if n <= 0 or m == 0:
        return 0.0, 0.0
    rng = np.random.default_rng(seed)
    rots, dts = [], []
    for _ in range(n):
        idx = rng.integers(0, m, size=m)
        c = estimate_pose_correction(
            rnd.kpts_render[idx],
            rnd.kpts_photo[idx],
            rnd.depth,
            rnd.cam_w,
            start,
            max_error_px=cfg.pose.max_error_px,
            min_inliers=cfg.pose.min_inliers,
        )
        if c.success:
            dt, dr = pose_difference(final, c.world_from_cam)
            rots.append(dr)
            dts.append(dt)
    if len(rots) < max(2, n // 2):  # the estimate is unstable under resampling
        return math.inf, math.inf
    return float(np.sqrt(np.mean(np.square(rots)))), float(np.sqrt(np.mean(np.square(dts))))


@dataclass(frozen=True, eq=False)
class _Rounds:
    """What the rounds of ``refine_pose`` left: the first round, the last round whose PnP
    succeeded (None when the first round's failed), its start and result poses, the steps
    (deg, scene units) and the rounds counted."""

    first: _Round
    last: _Round | None
    last_start: np.ndarray
    pose: np.ndarray
    steps: list[tuple[float, float]]
    n_done: int
    depth_scale: float | None


def _run_rounds(
    checker: Any,
    frame: Frame,
    pose: np.ndarray,
    photo_w: np.ndarray,
    camera: Any,
    size: tuple[int, int],
    rounds: int,
) -> _Rounds:
    """Up to ``rounds`` rounds from ``pose``; stops early when a round moves the pose by
    < 0.002 deg and < 1e-5 x the scene depth, or when a later round's PnP fails."""
    from pgt_check.geometry.transforms import pose_difference

    steps: list[tuple[float, float]] = []
    first: _Round | None = None
    rnd: _Round | None = None
    last_start = pose
    depth_scale: float | None = None
    n_done = 0
    prev: _Round | None = None
    for k in range(rounds):
        rnd = _round(checker, frame, pose, photo_w, camera, size)
        n_done = k + 1
        if k == 0:
            first = rnd
            d = rnd.depth[rnd.depth > 0]
            depth_scale = float(np.median(d)) if d.size else None
        if rnd.pose is None:
            if k == 0:
                return _Rounds(rnd, None, last_start, pose, steps, n_done, depth_scale)
            rnd = prev  # keep the last round whose PnP succeeded
            n_done -= 1
            break
        dt, dr = pose_difference(pose, rnd.pose)
        steps.append((dr, dt))
        last_start, pose = pose, rnd.pose
        prev = rnd
        if dr < 2e-3 and dt < 1e-5 * (depth_scale or 1.0):
            break
    assert first is not None and rnd is not None and rnd.pose is not None
    return _Rounds(first, rnd, last_start, pose, steps, n_done, depth_scale)


def refine_pose(
    checker: Any,
    frame: Frame,
    start: np.ndarray | None = None,
    *,
    start_kind: str = "checked",
    rounds: int = 3,
    bootstrap: int = 12,
    threshold_px: float | None = None,
    seed: int = 0,
) -> Correction:
    """Correct ``frame``'s pose by ``rounds`` of render -> raw match -> PnP from ``start``
    (default: the checked pose). ``checker``: a ``FrameChecker`` (its renderer, matcher and
    config are used). Stops early when a round moves the pose by < 0.002 deg and < 1e-5 x the
    scene depth. Never raises for an unusable frame: ``success`` False with a ``reason``.
    """
    from pgt_check.io import load_image
    from pgt_check.io.images import resize_image
    from pgt_check.io.photo import prepare_photo, working_scale

    if rounds < 1:
        raise ValueError(f"rounds must be >= 1, got {rounds}")
    checked = np.asarray(frame.world_from_cam, np.float64)
    pose = checked if start is None else np.asarray(start, np.float64)
    if frame.image_file is None or not Path(frame.image_file).is_file():
        return Correction(frame.frame_id, False, "image_missing", start=start_kind)
    photo, camera = prepare_photo(load_image(frame.image_file), frame.camera)
    size = max(working_scale(camera.width, camera.height, side)
               for side in (checker.config.match.resize_max, checker.config.correct.resize_max))
    photo_w = resize_image(photo, size)
    thr = (
        checker.config.verdict.threshold_for(camera.width, camera.height)
        if threshold_px is None
        else threshold_px
    )
    done = _run_rounds(checker, frame, pose, photo_w, camera, size, rounds)
    first_err = done.first.corner_error_px
    if done.last is None:
        return Correction(
            frame.frame_id,
            False,
            done.first.reason or "pnp_failed",
            corner_error_px_before=first_err,
            n_inliers=done.first.n_inliers,
            rounds=done.n_done,
            start=start_kind,
            depth=done.depth_scale,
        )
    return _correction(checker, frame, checked, done, thr, bootstrap, seed, start_kind)


def _correction(
    checker: Any,
    frame: Frame,
    checked: np.ndarray,
    done: _Rounds,
    thr: float,
    bootstrap: int,
    seed: int,
    start_kind: str,
) -> Correction:
    """The ``Correction`` of rounds that succeeded: uncertainty (bootstrap and last step),
    verified (raw corner error within ``thr``) and applied (verified and certain)."""
    from pgt_check.geometry.transforms import pose_difference

    rnd, final, steps = done.last, done.pose, done.steps
    assert rnd is not None
    boot_r, boot_t = _bootstrap(rnd, done.last_start, final, bootstrap, seed, checker.config)
    last_r, last_t = steps[-1] if steps else (0.0, 0.0)
    sigma_r = math.hypot(boot_r, last_r)
    sigma_t = math.hypot(boot_t, last_t)
    dt, dr = pose_difference(checked, final)
    err = rnd.corner_error_px
    verified = err is not None and err <= thr
    certain = math.isfinite(sigma_r) and sigma_r <= max(0.1, 0.5 * dr)
    applied = verified and certain
    reason = "" if applied else ("not_verified" if not verified else "uncertain")
    return Correction(
        frame.frame_id,
        True,
        reason,
        tuple(tuple(map(float, r)) for r in final),
        dr,
        dt,
        sigma_r,
        sigma_t,
        done.first.corner_error_px,
        err,
        rnd.n_inliers,
        done.n_done,
        start_kind,
        done.depth_scale,
        applied,
        tuple((float(a), float(b)) for a, b in steps),
    )
