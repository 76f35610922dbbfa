"""Pose corrections: iterate render -> match -> PnP from a frame's PnP estimate.

The measurement's PnP pose (``FrameMeasurement.pose``) is computed once, from the deciding path,
which may be the enhanced one (a render painted with a *reference* photo, whose own pose error
can bias it). ``refine_pose`` therefore uses it only as the starting point: every round renders
the mesh at the current pose and matches the **raw** render against the photo, lifts the render
keypoints with the render depth (mesh points) and solves PnP (pycolmap LO-RANSAC) for the next
pose. Where the run vouches for reference frames (``references``: frames whose own verdict
PASSed), each round also matches the render enhanced with one of them, in turn (the reference
photo placed on the mesh, ``checker.enhancer``): sharp photo texture where a scan's vertex
colours are blurred.

A round whose PnP fails for too few correspondences is solved together with the next
reference's round at the same pose (on the generated textureless scans the rounds had ended at
the first such round: reports/scenes_loso_generated.md). The final pose is one PnP on the
correspondences of every round together (a lifted point is a
mesh point whatever pose it was rendered at): on 7-Scenes the raw render gives 12-40 PnP
inliers per round, and each round's own PnP jumped by 0.3-0.6 deg around its fixed point
instead of converging, so the last round's pose was as far off as the first
(reports/corrections.md, issue #38).

Uncertainty (``sigma_rot_deg``, ``sigma_t``): the root sum of squares of (a) the bootstrap
spread of the pooled PnP (correspondences resampled with replacement, RMS distance of the
bootstrap poses to the final one) and (b) how far the final pose moved when the last round's
correspondences joined the pool (how far from converged; the last round's own update when
there was one round).
"""

from __future__ import annotations

import logging
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from pgt_check.correct.correction import Correction
from pgt_check.types import Frame

logger = logging.getLogger(__name__)


@dataclass(frozen=True, eq=False)
class _Round:
    """One round: the raw path's corner error, the round's own PnP pose (None on failure), and
    its correspondences: mesh points (world) and their photo pixels (working camera)."""

    corner_error_px: float | None
    pose: np.ndarray | None  # PnP result (None on failure)
    reason: str
    n_inliers: int
    points: np.ndarray  # (N, 3) world
    kpts_photo: np.ndarray  # (N, 2) working pixels
    depth: np.ndarray
    cam_w: Any


def _references_views(frame: Frame, references: Sequence[Frame], cam_w: Any) -> list[Any]:
    """The reference photos at the working scale of ``cam_w`` (unreadable ones left out)."""
    from pgt_check.enhance.base import ReferenceView
    from pgt_check.errors import InputError
    from pgt_check.io import load_image
    from pgt_check.io.images import resize_image
    from pgt_check.io.photo import prepare_photo

    out = []
    sx = cam_w.width / frame.camera.width
    for ref in references:
        if ref.image_file is None or not Path(ref.image_file).is_file():
            continue
        try:
            photo, cam = prepare_photo(load_image(ref.image_file), ref.camera)
        except InputError as err:
            logger.debug("reference %s left out of the correction: %s", ref.frame_id, err)
            continue
        size = (max(1, round(cam.width * sx)), max(1, round(cam.height * sx)))
        out.append(ReferenceView(ref.frame_id, resize_image(photo, size),
                                 cam.scaled(size[0] / cam.width, size[1] / cam.height),
                                 ref.world_from_cam))
    return out


@dataclass(frozen=True, eq=False)
class _Target:
    """The frame a correction refines and what every round matches against: the checker (its
    renderer, matcher, enhancer and config), the frame, its photo at the working size
    ``size`` (w, h) and the photo's camera (full size, undistorted)."""

    checker: Any
    frame: Frame
    photo_w: np.ndarray
    camera: Any
    size: tuple[int, int]


def _round(target: _Target, pose: np.ndarray, references: Sequence[Frame] = ()) -> _Round:
    """Render at ``pose``, match raw render (and the render enhanced with each reference) vs
    photo, the raw homography's corner error, the lifted correspondences and their PnP."""
    from pgt_check.enhance.base import View
    from pgt_check.geometry.pnp import estimate_pose_from_points, lift_keypoints
    from pgt_check.measure.steps import Clock, match_path

    checker, frame, photo_w, camera, size = (target.checker, target.frame, target.photo_w,
                                             target.camera, target.size)
    cfg = checker.config
    scale = (size[0] / camera.width, size[1] / camera.height)
    cam_w = camera.scaled(*scale)
    render = checker.renderer.render(cam_w, pose)
    empty3, empty2 = np.zeros((0, 3)), np.zeros((0, 2))
    if render.coverage_fraction < cfg.verdict.min_coverage:
        return _Round(None, None, "low_coverage", 0, empty3, empty2, render.depth, cam_w)
    path = match_path(checker.matcher, cfg.homography, render.rgb, photo_w, render.coverage,
                      size, scale, camera, Clock())
    pairs = [(path.kpts_render, path.kpts_photo)]
    if references:
        view = View(render, cam_w, pose)
        for ref in _references_views(frame, references, cam_w):
            enh = checker.enhancer.enhance(view, ref, checker.renderer)
            p = match_path(checker.matcher, cfg.homography, enh.image, photo_w,
                           render.coverage, size, scale, camera, Clock(),
                           checker.enhancer.detail_short_side)
            pairs.append((p.kpts_render, p.kpts_photo))
    pts, kp = [empty3], [empty2]
    for kr, kph in pairs:
        kr = np.asarray(kr, np.float64).reshape(-1, 2)
        if len(kr) == 0:
            continue
        valid, world = lift_keypoints(kr, render.depth, cam_w, pose)
        pts.append(world[valid])
        kp.append(np.asarray(kph, np.float64).reshape(-1, 2)[valid])
    points, kpts_photo = np.concatenate(pts), np.concatenate(kp)
    corr = estimate_pose_from_points(points, kpts_photo, cam_w, pose,
                                     max_error_px=cfg.pose.max_error_px,
                                     min_inliers=cfg.pose.min_inliers)
    return _Round(
        path.corner_error_px,
        corr.world_from_cam if corr.success else None,
        "" if corr.success or corr.reason is None else corr.reason.value,
        corr.n_inliers,
        points,
        kpts_photo,
        render.depth,
        cam_w,
    )


def _merged(rounds: Sequence[_Round], start: np.ndarray, cfg: Any) -> _Round | None:
    """The rounds made at one pose (each PnP failed) as one round: their correspondences
    together and one PnP on them (None when that fails too)."""
    c = _pooled_pnp(rounds, start, cfg)
    if not c.success:
        return None
    last = rounds[-1]
    return _Round(last.corner_error_px, c.world_from_cam, "", c.n_inliers,
                  np.concatenate([r.points for r in rounds]),
                  np.concatenate([r.kpts_photo for r in rounds]), last.depth, last.cam_w)


def _pooled_pnp(rounds: Sequence[_Round], start: np.ndarray, cfg: Any) -> Any:
    """One PnP on the correspondences of ``rounds`` together (``PoseCorrection``)."""
    from pgt_check.geometry.pnp import estimate_pose_from_points

    return estimate_pose_from_points(
        np.concatenate([r.points for r in rounds]),
        np.concatenate([r.kpts_photo for r in rounds]),
        rounds[-1].cam_w, start, max_error_px=cfg.pose.max_error_px,
        min_inliers=cfg.pose.min_inliers,
    )


def _bootstrap(
    points: np.ndarray, kpts_photo: np.ndarray, cam_w: Any, start: np.ndarray,
    final: np.ndarray, n: int, seed: int, cfg: Any
) -> tuple[float, float]:
    """RMS (rotation deg, centre distance) of PnP on resampled correspondences vs ``final``."""
    from pgt_check.geometry.pnp import estimate_pose_from_points
    from pgt_check.geometry.transforms import pose_difference

    m = len(points)
    if n <= 0 or m == 0:
        return 0.0, 0.0
    rng = np.random.default_rng(seed)
    rots, dts = [], []
    for _ in range(n):
        idx = rng.integers(0, m, size=m)
        c = estimate_pose_from_points(
            points[idx], kpts_photo[idx], cam_w, start,
            max_error_px=cfg.pose.max_error_px, min_inliers=cfg.pose.min_inliers,
        )
        if c.success and c.world_from_cam is not None:
            dt, dr = pose_difference(final, c.world_from_cam)
            rots.append(dr)
            dts.append(dt)
    if len(rots) < max(2, n // 2):  # the estimate is unstable under resampling
        return math.inf, math.inf
    return float(np.sqrt(np.mean(np.square(rots)))), float(np.sqrt(np.mean(np.square(dts))))


@dataclass(frozen=True, eq=False)
class _Rounds:
    """What the rounds of ``refine_pose`` left: the first round, the last round whose PnP
    succeeded (None when the first round's failed), every round whose PnP succeeded, the pose
    the rounds ended at, the steps (deg, scene units) and the rounds counted."""

    first: _Round
    last: _Round | None
    done: tuple[_Round, ...]
    last_start: np.ndarray
    pose: np.ndarray
    steps: list[tuple[float, float]]
    n_done: int
    depth_scale: float | None


def _run_rounds(
    target: _Target, pose: np.ndarray, rounds: int, references: Sequence[Frame] = ()
) -> _Rounds:
    """Up to ``rounds`` rounds from ``pose``; stops early when a round moves the pose by
    < 0.002 deg and < 1e-5 x the scene depth, or when a later round's PnP fails. A round whose
    correspondences are too few for a PnP of their own (a textureless photo: 12-32 matches)
    does not end the rounds while references are left: the next one is matched at the same
    pose and the rounds at that pose are solved together (``_merged``)."""
    from pgt_check.geometry.transforms import pose_difference

    steps: list[tuple[float, float]] = []
    first: _Round | None = None
    rnd: _Round | None = None
    last_start = pose
    depth_scale: float | None = None
    n_done = 0
    prev: _Round | None = None
    done: list[_Round] = []
    pending: list[_Round] = []
    for k in range(rounds):
        # the references take turns (one enhancement per round): the pool holds each one's
        # correspondences, so no single reference's own bias decides
        refs = (references[k % len(references)],) if references else ()
        rnd = _round(target, pose, refs)
        n_done = k + 1
        if k == 0:
            first = rnd
            d = rnd.depth[rnd.depth > 0]
            depth_scale = float(np.median(d)) if d.size else None
        if rnd.pose is None:
            # too few correspondences for a PnP of its own (a textureless photo): the next
            # reference is matched at the same pose and the rounds at it solved together
            pending.append(rnd)
            merged = _merged(pending, pose, target.checker.config) if len(pending) > 1 else None
            if merged is None:
                # (a render too empty to match is the same for every reference: not retried)
                if (k + 1 < rounds and len(pending) < len(references)
                        and rnd.reason != "low_coverage"):
                    continue
                if not done:
                    return _Rounds(first or rnd, None, (), last_start, pose, steps, n_done,
                                   depth_scale)
                rnd = prev  # keep the last round whose PnP succeeded
                n_done -= len(pending)  # the rounds at this pose do not count
                break
            rnd = merged
        new_pose = rnd.pose
        if new_pose is None:  # not reached: a merged round carries its PnP pose
            raise RuntimeError("a correction round without its PnP pose")
        pending = []
        done.append(rnd)
        dt, dr = pose_difference(pose, new_pose)
        steps.append((dr, dt))
        last_start, pose = pose, new_pose
        prev = rnd
        if dr < 2e-3 and dt < 1e-5 * (depth_scale or 1.0):
            break
    assert first is not None and rnd is not None and rnd.pose is not None
    return _Rounds(first, rnd, tuple(done), last_start, pose, steps, n_done, depth_scale)


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
    references: Sequence[Frame] = (),
) -> Correction:
    """Correct ``frame``'s pose by ``rounds`` of render -> raw match -> PnP from ``start``
    (default: the checked pose), the final pose a PnP on every round's correspondences.
    ``checker``: a ``FrameChecker`` (its renderer, matcher, enhancer and config are used).
    ``references``: frames the run vouches for (their own verdict PASSed), whose photos enhance
    each round's render (more, sharper matches; empty: the raw render alone). Stops early when
    a round moves the pose by < 0.002 deg and < 1e-5 x the scene depth. Never raises for an
    unusable frame: ``success`` False with a ``reason``.
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
    done = _run_rounds(_Target(checker, frame, photo_w, camera, size), pose, rounds, references)
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


def _pooled(done: _Rounds, cfg: Any) -> tuple[np.ndarray, int, tuple[float, float] | None]:
    """The final pose: the PnP on every successful round's correspondences together (the
    rounds' end pose where there was one round or the pooled PnP failed), its inliers, and how
    far it moved when the last round joined the pool (deg, scene units; None with one round)."""
    from pgt_check.geometry.transforms import pose_difference

    assert done.last is not None
    if len(done.done) < 2:
        return done.pose, done.last.n_inliers, None
    pooled = _pooled_pnp(done.done, done.pose, cfg)
    if not pooled.success:
        return done.pose, done.last.n_inliers, None
    before = _pooled_pnp(done.done[:-1], done.pose, cfg)
    moved = None
    if before.success:
        dt, dr = pose_difference(before.world_from_cam, pooled.world_from_cam)
        moved = (dr, dt)
    return pooled.world_from_cam, pooled.n_inliers, moved


def is_certain(sigma_rot_deg: float | None, drot_deg: float | None) -> bool:
    """Whether a correction's rotation uncertainty is small enough to apply it: at most
    0.1 deg or half the correction itself."""
    if sigma_rot_deg is None or drot_deg is None or not math.isfinite(sigma_rot_deg):
        return False
    return sigma_rot_deg <= max(0.1, 0.5 * drot_deg)


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

    rnd, steps = done.last, done.steps
    assert rnd is not None
    cfg = checker.config
    final, n_inliers, moved = _pooled(done, cfg)
    pool = done.done if moved is not None else (rnd,)
    points = np.concatenate([r.points for r in pool])
    kpts = np.concatenate([r.kpts_photo for r in pool])
    start = done.pose if moved is not None else done.last_start
    boot_r, boot_t = _bootstrap(points, kpts, rnd.cam_w, start, final, bootstrap, seed, cfg)
    last_r, last_t = moved if moved is not None else (steps[-1] if steps else (0.0, 0.0))
    sigma_r = math.hypot(boot_r, last_r)
    sigma_t = math.hypot(boot_t, last_t)
    dt, dr = pose_difference(checked, final)
    err = rnd.corner_error_px
    verified = err is not None and err <= thr
    applied = verified and is_certain(sigma_r, dr)
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
        n_inliers,
        done.n_done,
        start_kind,
        done.depth_scale,
        applied,
        tuple((float(a), float(b)) for a, b in steps),
        "raw" if verified else "",
    )
