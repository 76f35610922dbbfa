"""Per-frame pose accuracy: the error each frame's **absolute** evidence supports, in degrees,
scene units and px, with one-sided 95 % bounds (``frame_accuracy_columns``, the ``acc_*``
columns of frames.csv), and the image effect of a world rotation / translation that the run's
statement turns shared errors with (``world_sensitivity``).

The bound comes from ``geometry.frame_accuracy`` (robust fit of the camera-frame correction to
the frame's 2D-3D points, image-block bootstrap). A frame whose verdict rests on relative
evidence alone (reprojected references) has no bound of its own: relative evidence cannot see an
error it shares with its references. The run-level statement is ``verdict.accuracy``.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Collection, Mapping, Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from pgt_check.config import RunChecksConfig
from pgt_check.constants import FEATURE_ONLY_MIN_POINTS
from pgt_check.geometry.frame_accuracy import FrameAccuracy, frame_accuracy
from pgt_check.measure.record import FrameMeasurement, source_path
from pgt_check.verdict.calibration import CameraCalibration, camera_matrix
from pgt_check.verdict.judgement import Judgement, Verdict

logger = logging.getLogger(__name__)

#: frames.csv columns of the per-frame accuracy, with their meaning (docs/outputs.md)
ACCURACY_COLUMNS: dict[str, str] = {
    "acc_rot_deg": "estimated rotation error of the pose, deg (from its absolute evidence)",
    "acc_rot_bound_deg": "95 % upper bound of the rotation error, deg",
    "acc_t": "estimated camera-centre error, scene units",
    "acc_t_bound": "95 % upper bound of the camera-centre error, scene units",
    "acc_px": "mean image displacement of the estimated error at the frame's points, px",
    "acc_px_bound": "95 % upper bound of that displacement, px",
    "acc_noise_deg": "rotation the frame cannot tell from zero (bootstrap noise, 95 %), deg",
    "acc_noise_t": "camera-centre shift it cannot tell from zero, scene units",
    "acc_noise_px": "image displacement it cannot tell from zero, px",
    "acc_px_per_deg": "sensitivity: corner error per degree of rotation as the check measures "
    "it (the points' image motion fitted by a homography), px (median over error axes)",
    "acc_px_per_unit": "the same per scene unit of camera translation, px (median over error "
    "axes; depends on the points' depths)",
    "acc_low_px_per_deg": "the same at the 5 % quantile over error axes (95 % of axes move the "
    "corners more), px per degree",
    "acc_low_px_per_unit": "the same at the 5 % quantile over error axes, px per scene unit",
    "acc_pts_px_per_deg": "image motion at the frame's evidence points per degree of rotation, "
    "px (mean over the camera axes)",
    "acc_pts_px_per_unit": "the same per scene unit of camera translation, px",
    "acc_depth": "median depth of the fit's points, scene units",
    "acc_points": "2D-3D points of the fit (inliers / all)",
    "acc_evidence": "what the bound rests on: the absolute sources (raw, enhanced, edges) of "
    "the paths that agree with the verdict, "
    "'+calibration removed' when a calibration error was taken out first; '' = no bound",
    "acc_reason": "why the frame has no bound ('' when it has one)",
}

_MAX_POINTS = 400  # per frame (evenly spaced): the fit's cost stays a few ms



def bound_points(
    evidence: Any, features_only: bool = True, paths: Collection[str] | None = None
) -> tuple[np.ndarray, np.ndarray, tuple[str, ...]]:
    """(pts2d (N, 2), pts_cam (N, 3), sources) of an ``AbsoluteEvidence`` that the per-frame
    bound is fitted to: the feature paths' points alone when they have
    ``FEATURE_ONLY_MIN_POINTS`` (and ``features_only``), else every point (also when the split
    is unknown). ``paths``: only the sources of these paths (raw, enhanced, edges; None: all;
    with the split unknown, all points only when every source is among them, else none)."""
    split = evidence.by_source()
    if paths is not None:
        if not split:
            if all(source_path(s) in paths for s in evidence.sources):
                return bound_points(evidence, features_only)
            return np.zeros((0, 2)), np.zeros((0, 3)), ()
        split = {k: v for k, v in split.items() if source_path(k) in paths}
        if not split:
            return np.zeros((0, 2)), np.zeros((0, 3)), ()
    feats = {k: v for k, v in split.items() if k != "edges"}
    if features_only and split and len(feats) < len(split):
        n = sum(len(v[0]) for v in feats.values())
        if n >= FEATURE_ONLY_MIN_POINTS:
            return (np.concatenate([v[0] for v in feats.values()]),
                    np.concatenate([v[1] for v in feats.values()]), tuple(feats))
    if paths is not None:
        return (np.concatenate([v[0] for v in split.values()]),
                np.concatenate([v[1] for v in split.values()]), tuple(split))
    p2 = np.asarray(evidence.pts2d, np.float64).reshape(-1, 2)
    pc = np.asarray(evidence.pts_cam, np.float64).reshape(-1, 3)
    return p2, pc, tuple(evidence.sources)


@dataclass(frozen=True)
class FrameBound:
    """One frame's pose accuracy from its absolute evidence: the fit (None when the frame has
    no absolute evidence), the sources it rests on (``acc_evidence``) and, without a bound,
    why (``acc_reason``)."""

    accuracy: FrameAccuracy | None = None
    evidence: str = ""
    reason: str = "no_absolute_evidence"

    @property
    def bounded(self) -> bool:
        """Whether the frame has a rotation bound (``acc_rot_bound_deg``)."""
        return self.accuracy is not None and self.accuracy.success

    def columns(self) -> dict[str, Any]:
        """The frame's ``ACCURACY_COLUMNS`` (frames.csv)."""
        row: dict[str, Any] = dict.fromkeys(ACCURACY_COLUMNS)
        row.update(acc_evidence=self.evidence, acc_reason=self.reason)
        if self.accuracy is not None:
            row.update(_columns(self.accuracy))
        return row


def frame_bounds(
    measurements: Sequence[FrameMeasurement],
    calibrations: Mapping[str, CameraCalibration] | None = None,
    paths: Mapping[str, Collection[str] | None] | None = None,
) -> dict[str, FrameBound]:
    """frame id -> the ``FrameBound`` of every measurement. ``calibrations``: camera id -> a
    calibration error to take out of the evidence first (``--remove-calibration``,
    ``--calibration-from``). ``paths``: frame id -> the paths whose evidence the bound may
    rest on (``agreeing_paths``: those that agree with the frame's verdict; missing or None:
    all): a bound fitted to the points of a path the verdict overruled measures that path's
    error, not the pose's (issue #38: PASS frames decided by the edge path at 5-12 px were
    stated to within 13 deg by the enhanced path's 24-42 px)."""
    out: dict[str, FrameBound] = {}
    for i, m in enumerate(measurements):
        out[m.frame_id] = FrameBound()
        if m.evidence is None or not len(m.evidence) or m.world_from_cam is None or not m.intrinsics:
            continue
        k = camera_matrix(m.intrinsics)
        cal = (calibrations or {}).get(m.camera_id)
        keep = (paths or {}).get(m.frame_id)
        fa, sources = _fit(m, i, k, cal, True, keep)
        if not fa.success and sources != _all_sources(m.evidence, keep):
            # the feature points alone give no bound: every point (edges included)
            fa, sources = _fit(m, i, k, cal, False, keep)
        if not sources:
            out[m.frame_id] = FrameBound(reason="no_agreeing_absolute_evidence")
            continue
        evidence = "+".join(sources) + ("+calibration removed" if cal is not None else "")
        out[m.frame_id] = FrameBound(fa, evidence if fa.success else "", fa.reason if not
                                     fa.success else "")
    return out


def pass_bound(
    m: FrameMeasurement,
    index: int,
    bound: FrameBound,
    calibration: CameraCalibration | None = None,
    paths: Collection[str] | None = None,
) -> FrameBound:
    """The bound of a PASS (``bounded_pass`` checks its ``effect_bound_px``; frames.csv
    and the accuracy statement read it): the frame's bound (``frame_bounds``), or, where that
    rests on the feature points alone while other agreeing evidence (the geometric edges) was
    left out of it, the bound from every agreeing point. The feature-only rule guards the pose
    bound of frames in general (edge points carry no parallax, so their fit turns a shift into
    a rotation); a PASS that rests on the edges too must be stated and checked on what it rests
    on (issue #38, 7-Scenes: PASS frames whose edges agree at 10-15 px were UNVERIFIABLE on a
    22-28 px bound from 44-51 raw inliers)."""
    if not bound.bounded or m.evidence is None or m.world_from_cam is None or not m.intrinsics:
        return bound
    used = tuple(bound.evidence.replace("+calibration removed", "").split("+"))
    if set(_all_sources(m.evidence, paths)) <= set(used):
        return bound
    every, sources = _fit(m, index, camera_matrix(m.intrinsics), calibration, False, paths)
    if not every.success or not sources:
        return bound
    return FrameBound(every, "+".join(sources) + ("+calibration removed" if calibration
                                                   is not None else ""), "")


#: the reason prefix of a PASS whose own 95 % bound exceeds the threshold
BOUND_ABOVE_THRESHOLD = "bound_above_threshold"


def bounded_pass(j: Judgement, effect_bound_px: float | None, threshold_px: float) -> Judgement:
    """``j`` where a PASS and the frame's 95 % bound agree; UNVERIFIABLE
    (``bound_above_threshold``) where the evidence the PASS rests on bounds the image error
    only beyond the threshold (``effect_bound_px``: the per-frame bound's displacement at its
    points, ``verdict.frame_bounds``; None: no bound, ``j`` unchanged). A homography fitted to
    a few noisy matches can land within the threshold by chance while the same points cannot
    exclude an error several times larger (colourless 7-Scenes with MaRINeR: PASS frames with
    95 % bounds of 17-110 px against 16 px, "verified to within" tens of degrees)."""
    if j.verdict is not Verdict.PASS or effect_bound_px is None or not math.isfinite(
            effect_bound_px) or effect_bound_px <= threshold_px:
        return j
    reason = (f"{BOUND_ABOVE_THRESHOLD} (the evidence bounds the error to {effect_bound_px:.1f} "
              f"px at 95 %, above the {threshold_px:.1f} px threshold: it cannot tell an error "
              "above the threshold from none)")
    return replace(j, verdict=Verdict.UNVERIFIABLE, reason=reason)


def _all_sources(evidence: Any, paths: Collection[str] | None) -> tuple[str, ...]:
    """The evidence's sources among ``paths`` (None: all)."""
    return tuple(s for s in evidence.sources if paths is None or source_path(s) in paths)


def agreeing_paths(
    outcomes: Mapping[str, Any], decided_by: str
) -> tuple[str, ...] | None:
    """The paths whose evidence a frame's bound rests on: those whose own outcome
    (``verdict.decide.path_outcomes``) is the deciding path's PASS or FAIL; None (every
    path) when no path decided or it is not verifiable."""
    o = outcomes.get(decided_by) if decided_by else None
    if o is None or o[0].value not in ("PASS", "FAIL"):
        return None
    return tuple(n for n in ("raw", "enhanced", "edges")
                 if outcomes.get(n) is not None and outcomes[n][0] is o[0])


def frame_accuracy_columns(
    measurements: Sequence[FrameMeasurement],
    calibrations: Mapping[str, CameraCalibration] | None = None,
) -> dict[str, dict[str, Any]]:
    """frame id -> the ``ACCURACY_COLUMNS`` of every measurement (``frame_bounds`` as columns)."""
    return {fid: b.columns() for fid, b in frame_bounds(measurements, calibrations).items()}


def _fit(
    m: FrameMeasurement, i: int, k: np.ndarray, cal: CameraCalibration | None,
    features_only: bool, paths: Collection[str] | None = None,
) -> tuple[FrameAccuracy, tuple[str, ...]]:
    """The frame's bound from ``bound_points`` (at most ``_MAX_POINTS``, calibration taken
    out when given) and the sources it rests on (() and no fit when none is left)."""
    p2, pc, sources = bound_points(m.evidence, features_only, paths)
    if not sources:
        return FrameAccuracy(False, "too_few_points"), ()
    if len(p2) > _MAX_POINTS:
        keep = np.linspace(0, len(p2) - 1, _MAX_POINTS).round().astype(int)
        p2, pc = p2[keep], pc[keep]
    if cal is not None:
        p2 = cal.remove(_evidence(m, i, k, p2, pc)).pts2d
    return frame_accuracy(p2, pc, k, m.width, m.height), sources


def _evidence(m: FrameMeasurement, i: int, k: np.ndarray, p2: np.ndarray, pc: np.ndarray) -> Any:
    """The frame's points as run-level ``FrameEvidence`` (to take a calibration out)."""
    from pgt_check.geometry.shared_errors import FrameEvidence

    wfc = np.asarray(m.world_from_cam, np.float64)
    return FrameEvidence(m.frame_id, i, m.camera_id, wfc, k, m.width, m.height, p2,
                         pc @ wfc[:3, :3].T + wfc[:3, 3])


def _columns(fa: FrameAccuracy) -> dict[str, Any]:
    if not fa.success:
        return {"acc_reason": fa.reason, "acc_points": f"{fa.n_inliers}/{fa.n_points}"}
    return {
        "acc_rot_deg": fa.rotation_deg,
        "acc_rot_bound_deg": fa.rotation_bound_deg,
        "acc_t": fa.translation,
        "acc_t_bound": fa.translation_bound,
        "acc_px": fa.effect_px,
        "acc_px_bound": fa.effect_bound_px,
        "acc_noise_deg": fa.rotation_noise_deg,
        "acc_noise_t": fa.translation_noise,
        "acc_noise_px": fa.effect_noise_px,
        "acc_px_per_deg": fa.px_per_deg,
        "acc_px_per_unit": fa.px_per_unit,
        "acc_low_px_per_deg": fa.low_px_per_deg,
        "acc_low_px_per_unit": fa.low_px_per_unit,
        "acc_pts_px_per_deg": fa.points_px_per_deg,
        "acc_pts_px_per_unit": fa.points_px_per_unit,
        "acc_depth": fa.depth,
        "acc_points": f"{fa.n_inliers}/{fa.n_points}",
        "acc_reason": "",
    }


def world_sensitivity(measurements: Sequence[FrameMeasurement]) -> tuple[float, float]:
    """(px per degree, px per scene unit) of a shared error about / along the world axis where
    it is smallest (``world_axis_sensitivity``; the limit holds whatever the axis)."""
    rot, tra = world_axis_sensitivity(measurements)

    def least(a: np.ndarray) -> float:
        return float(np.nanmin(a)) if np.isfinite(a).any() else float("nan")

    return least(rot), least(tra)


def world_axis_sensitivity(
    measurements: Sequence[FrameMeasurement],
) -> tuple[np.ndarray, np.ndarray]:
    """(px per degree, px per scene unit) per world axis x, y, z, each (3,) float64: the image
    effect of rotating the
    world by 1 deg about the camera centroid, or shifting it by 1 unit, as the registration
    check measures it (median over frames of the mean displacement of a frame's evidence
    points), about / along each world axis. A world rotation also moves the camera centres,
    which on views around an object undoes much of its image effect: a camera-frame
    sensitivity would overstate it. NaN without evidence."""
    from pgt_check.geometry.transforms import axis_angle_to_rotmat
    from pgt_check.verdict.shared import frame_evidence

    ev = [e for e in frame_evidence(measurements) if len(e.pts3d)]
    if not ev:
        return np.full(3, np.nan), np.full(3, np.nan)
    c = np.mean([e.world_from_cam[:3, 3] for e in ev], axis=0)

    def effect(move) -> float:
        per = []
        for e in ev:
            r, t = e.world_from_cam[:3, :3], e.world_from_cam[:3, 3]
            x0 = (e.pts3d - t) @ r
            x1 = (move(e.pts3d) - t) @ r
            ok = (x0[:, 2] > 1e-9) & (x1[:, 2] > 1e-9)
            if not ok.any():
                continue
            u0 = (x0[ok] @ e.K.T)[:, :2] / x0[ok, 2:3]
            u1 = (x1[ok] @ e.K.T)[:, :2] / x1[ok, 2:3]
            per.append(float(np.mean(np.linalg.norm(u1 - u0, axis=1))))
        return float(np.median(per)) if per else float("nan")

    eye = np.eye(3)
    step_deg, step_units = 0.1, 1e-3 * max(float(np.median(
        [np.linalg.norm(e.pts3d - e.world_from_cam[:3, 3], axis=1).mean() for e in ev])), 1e-9)
    rots = [axis_angle_to_rotmat(a, step_deg) for a in eye]
    rot = np.array([effect(lambda x, rr=rr: (x - c) @ rr.T + c) for rr in rots]) / step_deg
    tra = np.array([effect(lambda x, d=a: x + step_units * d) for a in eye]) / step_units
    return rot, tra


def trusted_calibrations(
    config: RunChecksConfig, camera_ids: Sequence[str]
) -> dict[str, CameraCalibration]:
    """The trusted run's calibration errors (``--calibration-from``) the bounds take out when
    the run-level checks are off (with them on, ``SharedChecks.removed_calibrations`` holds
    what the checks removed); {} without a trusted run."""
    if not config.calibration_from:
        return {}
    from pgt_check.verdict.calibration import trusted_calibration

    return trusted_calibration(config.calibration_from, sorted(set(camera_ids)))
