"""Run-level checks of errors that many frames share: registration of the whole trajectory to
the mesh, drift along it, and per-camera calibration (see README "What a verdict proves").

They pool the absolute evidence of every frame (``FrameMeasurement.evidence``: 2D-3D
correspondences from the raw render and other absolute paths, never from reprojection) and fit
one small model to all of it (``pgt_check.geometry.shared_errors``). Each check gets a status:

* ``passed``: measured, and the shared error is below the threshold with confidence (the upper
  bound of its 95 % interval of image displacement);
* ``failed``: above the threshold with confidence (the lower bound exceeds it);
* ``inconclusive``: measured, but the interval straddles the threshold;
* ``not_checked``: too little absolute evidence (few frames or points);
* for calibration also ``finding``: a significant shared camera-frame error that stays below the
  per-frame threshold (reported, frames still judged; ``--remove-calibration`` judges them after
  removing it).

The threshold (``VerdictConfig.shared_threshold_px``; default 0.15 x the per-frame
threshold) is lower than the per-frame one because pooled evidence is far more precise, and
errors every frame shares matter more.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from pgt_check.config import RunConfig
from pgt_check.measure.record import FrameMeasurement
from pgt_check.verdict.calibration import (
    CameraCalibration,
    camera_matrix,
    frame_homographies,
    trusted_calibration,
)
from pgt_check.verdict.status import FAILED, FINDING, INCONCLUSIVE, NOT_CHECKED, PASSED
from pgt_check.verdict.texture import texture_entry

logger = logging.getLogger(__name__)



@dataclass(frozen=True)
class SharedChecks:
    """Results of the run-level checks (``summary()`` is the summary.json section).

    ``drift_px`` / ``drift_flagged``: per frame id, the drift score and whether the frame lies in
    a flagged segment. ``calibration_homographies``: camera id -> (3, 3) photo_from_render of the
    estimated calibration error (for ``--remove-calibration``).
    """

    threshold_px: float
    registration: dict[str, Any]
    similarity: dict[str, Any]
    drift: dict[str, Any]
    calibration: dict[str, dict[str, Any]]
    drift_px: dict[str, float] = field(default_factory=dict)
    drift_flagged: frozenset[str] = frozenset()
    calibration_homographies: dict[str, np.ndarray] = field(default_factory=dict)
    #: frames whose absolute evidence disagrees with the shared correction (an error of their
    #: own): left out of the pooled fits, and not covered by a passed registration check
    left_out: frozenset[str] = frozenset()
    #: frame id -> photo_from_render of the calibration error at that frame's depth (only
    #: where a camera-frame translation was estimated; else the camera's homography holds)
    frame_homographies: dict[str, np.ndarray] = field(default_factory=dict)
    #: the drift check's threshold (``DRIFT_THRESHOLD_FACTOR`` x ``threshold_px``)
    drift_threshold_px: float = float("nan")
    #: mesh colours against mesh geometry (``texture_entry``; empty when not run)
    texture: dict[str, Any] = field(default_factory=dict)
    #: with ``--calibration-from``, per camera id: what is left of the calibration after
    #: removing the trusted run's (``_calibration_change_entry``); a FAILED camera's frames FAIL
    calibration_change: dict[str, dict[str, Any]] = field(default_factory=dict)

    def calibration_homography(self, frame_id: str, camera_id: str) -> np.ndarray | None:
        """The calibration error's photo_from_render for this frame (None if not estimated)."""
        h = self.frame_homographies.get(frame_id)
        return self.calibration_homographies.get(camera_id) if h is None else h

    @property
    def registration_status(self) -> str:
        """The worse of the rigid and the similarity check."""
        order = (FAILED, INCONCLUSIVE, NOT_CHECKED, PASSED)
        sts = {self.registration.get("status"), self.similarity.get("status")}
        for s in order:
            if s in sts:
                return s
        return NOT_CHECKED

    def summary(self) -> dict[str, Any]:
        return {
            "threshold_px": self.threshold_px,
            "registration": self.registration,
            "similarity": self.similarity,
            "drift": self.drift,
            "calibration": self.calibration,
            **({"texture": self.texture} if self.texture else {}),
            **(
                {"calibration_change": self.calibration_change}
                if self.calibration_change
                else {}
            ),
        }

    def calibration_changed(self, camera_id: str) -> dict[str, Any] | None:
        """The calibration-change entry of this camera when it FAILED (else None)."""
        e = self.calibration_change.get(camera_id)
        return e if e is not None and e.get("status") == FAILED else None


#: the drift check's threshold relative to the shared one. A drift window is fitted on a few
#: frames, where view-dependent errors the model lacks show as a local correction of a few px:
#: on the 100 given 7-Scenes frames (RGB photos with depth-camera poses) up to 3.5 px where
#: the camera looks at near surfaces or turns fast, against 2.4 px of shared threshold
DRIFT_THRESHOLD_FACTOR = 2.0


def shared_threshold(measurements: Sequence[FrameMeasurement], config: RunConfig) -> float:
    """The shared-error threshold in photo pixels (median over the frames' image sizes)."""
    v = config.verdict
    if v.shared_threshold_px is not None:
        return float(v.shared_threshold_px)
    if not measurements:
        return float("nan")
    per_frame = [v.threshold_for(m.width, m.height) for m in measurements]
    return float(v.shared_threshold_rel * np.median(per_frame))


#: points per frame in the pooled run-level fits: one frame, one vote. A frame whose evidence
#: has several sources (raw matches + edges) would otherwise weigh up to twice as much as one
#: with edges alone (castle, `accurate` preset, drifting segment: the 4 drifting frames, with
#: XFeat matches of their shaded renders beside their edges, made the registration fail and
#: all 10 frames FAIL; capped, it passes and the drift is found, AUC 1.00)
MAX_FRAME_EVIDENCE_POINTS = 200


def frame_evidence(measurements: Sequence[FrameMeasurement]) -> list[Any]:
    """The frames that carry absolute evidence, as ``FrameEvidence`` (index = trajectory order),
    each with at most ``MAX_FRAME_EVIDENCE_POINTS`` points (evenly spaced over its sources)."""
    from pgt_check.geometry.shared_errors import FrameEvidence

    out = []
    for i, m in enumerate(measurements):
        if m.evidence is None or m.world_from_cam is None or m.intrinsics is None:
            continue
        wfc = np.asarray(m.world_from_cam, np.float64)
        pts_cam = np.asarray(m.evidence.pts_cam, np.float64).reshape(-1, 3)
        pts2d = np.asarray(m.evidence.pts2d, np.float64).reshape(-1, 2)
        if len(pts2d) > MAX_FRAME_EVIDENCE_POINTS:
            keep = np.linspace(0, len(pts2d) - 1, MAX_FRAME_EVIDENCE_POINTS).round().astype(int)
            pts_cam, pts2d = pts_cam[keep], pts2d[keep]
        out.append(
            FrameEvidence(
                frame_id=m.frame_id,
                index=i,
                camera_id=m.camera_id,
                world_from_cam=wfc,
                K=camera_matrix(m.intrinsics),
                width=m.width,
                height=m.height,
                pts2d=pts2d,
                pts3d=pts_cam @ wfc[:3, :3].T + wfc[:3, 3],
            )
        )
    return out


def _ci(x: Any) -> list[float] | None:
    if x is None:
        return None
    a = [float(v) for v in np.asarray(x, np.float64).reshape(-1)]
    return a if all(math.isfinite(v) for v in a) else None


def _f(x: Any) -> float | None:
    x = float(x)
    return x if math.isfinite(x) else None


def _status(success: bool, effect_ci: Any, effect: float, threshold: float) -> str:
    if not success:
        return NOT_CHECKED
    lo, hi = effect_ci if _ci(effect_ci) else (effect, effect)
    if lo > threshold:
        return FAILED
    if hi <= threshold:
        return PASSED
    return INCONCLUSIVE


def _registration_entry(est: Any, threshold: float, kind: str) -> dict[str, Any]:
    status = _status(est.success, est.effect_px_ci, est.effect_px, threshold)
    entry: dict[str, Any] = {
        "status": status,
        "reason": est.reason,
        "kind": kind,
        "angle_deg": _f(est.angle_deg),
        "angle_deg_ci": _ci(est.angle_deg_ci),
        "translation": _f(est.translation),
        "translation_ci": _ci(est.translation_ci),
        "translation_rel_depth": _f(est.translation_frac),
        "translation_rel_depth_ci": _ci(est.translation_frac_ci),
        "scale": _f(est.scale),
        "scale_ci": _ci(est.scale_ci),
        "effect_px": _f(est.effect_px),
        "effect_px_ci": _ci(est.effect_px_ci),
        "n_frames": est.n_frames,
        "n_points": est.n_points,
        "n_inliers": est.n_inliers,
        "ambiguous_with_calibration": bool(est.ambiguous_with_calibration),
        "corrected_world_from_world": (
            None
            if est.corrected_world_from_world is None
            else np.asarray(est.corrected_world_from_world).tolist()
        ),
    }
    entry["message"] = _registration_message(entry, threshold)
    return entry


def _registration_message(e: dict[str, Any], threshold: float) -> str:
    what = "similarity" if e["kind"] == "similarity" else "rigid registration"
    if e["status"] == NOT_CHECKED:
        return (
            f"{what} of the trajectory to the mesh not checked: too little absolute "
            f"evidence ({e['reason'] or 'no frames'}; {e['n_frames']} frames)"
        )
    lo, hi = e["effect_px_ci"] or (e["effect_px"], e["effect_px"])
    scale = f", scale {e['scale']:.4f}" if e["kind"] == "similarity" else ""
    rel = e["translation_rel_depth"]
    nums = (
        f"{e['angle_deg']:.2f} deg, {e['translation']:.4g} scene units"
        + (f" ({100 * rel:.1f} % of the scene depth)" if rel is not None else "")
        + f"{scale}; moves the images by {e['effect_px']:.1f} px (95 % {lo:.1f}-{hi:.1f}) "
        f"over {e['n_frames']} frames"
    )
    verdict = {
        PASSED: f"passed: below {threshold:.1f} px",
        FAILED: f"FAILED: the trajectory is misregistered to the mesh (above {threshold:.1f} px)",
        INCONCLUSIVE: f"inconclusive: the interval straddles {threshold:.1f} px",
    }[e["status"]]
    amb = (
        " (not separable from a calibration error with these views)"
        if e["ambiguous_with_calibration"]
        else ""
    )
    return f"{what} {verdict}: correction {nums}{amb}"


def _calibration_entry(est: Any, shared_thr: float, frame_thr: float) -> dict[str, Any]:
    status = _status(est.success, est.effect_px_ci, est.effect_px, shared_thr)
    if status == FAILED:
        lo = (_ci(est.effect_px_ci) or [est.effect_px])[0]
        status = FAILED if lo > frame_thr else FINDING
    entry = {
        "status": status,
        "reason": est.reason,
        "effect_px": _f(est.effect_px),
        "effect_px_ci": _ci(est.effect_px_ci),
        "principal_point_shift_px": _ci(est.principal_point_shift_px),
        "rotation_deg": _f(est.equivalent_rotation_deg),
        "rotation_deg_ci": _ci(est.equivalent_rotation_deg_ci),
        "roll_deg": _f(est.roll_deg),
        "focal_scale": _f(est.focal_scale),
        "focal_scale_ci": _ci(est.focal_scale_ci),
        "n_frames": est.n_frames,
        "separable_from_registration": bool(est.separable),
        # true_cam_from_checked_cam: what --calibration-from applies to another run
        "rotation": None if est.rotation is None else np.asarray(est.rotation).tolist(),
        "translation": _ci(est.translation) if est.translation_fitted else None,
        # (3, 2): the 95 % interval of each component
        "translation_ci": (
            [_ci(row) for row in np.asarray(est.translation_ci)] if est.translation_fitted else None
        ),
    }
    if status == NOT_CHECKED:
        entry["message"] = f"calibration not checked: no absolute evidence ({est.reason})"
        return entry
    pp = entry["principal_point_shift_px"] or [float("nan")] * 2
    entry["message"] = (
        f"calibration {status}: every frame of this camera is displaced by "
        f"{est.effect_px:.1f} px: principal point off by ({pp[0]:+.1f}, {pp[1]:+.1f}) px or a "
        f"camera-to-rig rotation of {est.equivalent_rotation_deg:.2f} deg "
        f"(roll {est.roll_deg:+.2f} deg), focal length x{est.focal_scale:.4f}"
        + (
            ", camera-to-rig translation ({:+.4f}, {:+.4f}, {:+.4f}) scene units".format(
                *est.translation
            )
            if est.translation_fitted
            else ""
        )
        + ("" if est.separable else "; not separable from registration with these views")
    )
    return entry


def _calibration_change_entry(est: Any, threshold: float) -> dict[str, Any]:
    """This run's calibration against a trusted run's (``--calibration-from``): the estimate on
    the evidence after removing the trusted calibration. FAILED when it moves the images by
    more than the shared threshold with confidence: the camera changed (focal length,
    principal point, mounting) since the trusted run, and its frames are not PASS."""
    entry = _calibration_entry(est, threshold, threshold)
    if entry["status"] == NOT_CHECKED:
        entry["message"] = f"calibration change not checked: no absolute evidence ({est.reason})"
        return entry
    entry["status"] = _status(est.success, est.effect_px_ci, est.effect_px, threshold)
    lo, hi = entry["effect_px_ci"] or (est.effect_px, est.effect_px)
    what = {
        FAILED: "calibration CHANGED since the trusted run",
        PASSED: "calibration as in the trusted run",
        INCONCLUSIVE: "calibration change since the trusted run inconclusive",
    }[entry["status"]]
    pp = entry["principal_point_shift_px"] or [float("nan")] * 2
    entry["message"] = (
        f"{what}: what is left moves the images by {est.effect_px:.1f} px (95 % {lo:.1f}-"
        f"{hi:.1f}, threshold {threshold:.1f}): principal point ({pp[0]:+.1f}, {pp[1]:+.1f}) px, "
        f"roll {est.roll_deg:+.2f} deg, focal length x{est.focal_scale:.4f}"
    )
    return entry


def _drift_coverage(
    est: Any, ids: list[str], threshold: float
) -> tuple[dict, dict, list[tuple[int, int]], set]:
    """Per trajectory frame (``ids``, trajectory order = ``FrameEvidence.index``): drift score
    and lower bound, and the flagged segments as (first, last) positions.

    Drift is a property of the trajectory segment, not of one frame's evidence: a frame without
    evidence of its own between the first and last frame with evidence gets the score
    interpolated along the trajectory; it is flagged when it lies in a flagged segment, and a
    segment grows over adjacent such frames whose interpolated lower bound exceeds the
    threshold. Returns (score, low, segments, ids with interpolated values)."""
    index = np.asarray(est.frame_index, np.float64)
    own = {fid: k for k, fid in enumerate(est.frame_ids)}
    score, low, interpolated = {}, {}, set()
    for i, fid in enumerate(ids):
        if fid in own:
            score[fid] = float(est.frame_score_px[own[fid]])
            low[fid] = float(est.frame_score_low_px[own[fid]])
        elif len(index) and index[0] <= i <= index[-1]:
            score[fid] = float(np.interp(i, index, est.frame_score_px))
            low[fid] = float(np.interp(i, index, est.frame_score_low_px))
            interpolated.add(fid)

    def grows(i: int) -> bool:
        return 0 <= i < len(ids) and ids[i] in interpolated and low[ids[i]] > threshold

    segments = []
    for a, b in est.segments:
        a, b = int(a), min(int(b), len(ids) - 1)
        while grows(a - 1):
            a -= 1
        while grows(b + 1):
            b += 1
        segments.append((a, b))
    return score, low, segments, interpolated


def _drift_entry(est: Any, ids: list[str], threshold: float) -> tuple[dict, dict, frozenset]:
    """The drift section of the summary, the per-frame scores and the flagged frame ids;
    ``ids``: every frame of the run in trajectory order (with or without evidence)."""
    if not est.success:
        return (
            {
                "status": NOT_CHECKED,
                "reason": est.reason,
                "message": f"drift not checked ({est.reason})",
            },
            {},
            frozenset(),
        )
    score, low, runs, interpolated = _drift_coverage(est, ids, threshold)
    flagged = {fid for fid, f in zip(est.frame_ids, est.frame_flagged, strict=True) if f}
    flagged = frozenset(flagged.union(*({ids[i] for i in range(a, b + 1)} for a, b in runs)))
    segments = [[ids[a], ids[b]] for a, b in runs]
    status = FAILED if flagged else PASSED
    entry = {
        "status": status,
        "reason": est.reason,
        "threshold_px": threshold,
        "segments": segments,
        "n_windows": len(est.windows),
        "per_frame": [
            {
                "frame_id": fid,
                "index": i,
                "effect_px": _f(score[fid]),
                "lo_px": _f(low[fid]),
                "flagged": fid in flagged,
                "own_evidence": fid not in interpolated,
            }
            for i, fid in enumerate(ids)
            if fid in score
        ],
        "message": (
            f"drift FAILED: {len(segments)} segment(s) move away from the mesh by more than "
            f"{threshold:.1f} px: " + ", ".join(f"{a} .. {b}" for a, b in segments)
            if flagged
            else f"drift passed: no window moves by more than {threshold:.1f} px"
        ),
    }
    return entry, score, flagged


def _shared_or_not(entry: dict[str, Any], residuals: np.ndarray, tol_px: float) -> dict:
    """A FAILED registration entry becomes INCONCLUSIVE when fewer than half of the frames
    agree with the correction (residual within ``tol_px`` after it): the frames then carry
    errors of their own, and one shared correction does not describe them (e.g. 3 frames, 2
    with large pose errors, which leaving frames out cannot separate)."""
    finite = residuals[np.isfinite(residuals)]
    agree = float(np.mean(finite <= tol_px)) if len(finite) else 0.0
    entry["frames_agreeing"] = agree
    if entry.get("status") == FAILED and agree < 0.5:
        entry["status"] = INCONCLUSIVE
        what = entry["message"].split(" FAILED", 1)[0]
        entry["message"] = (
            f"{what} inconclusive: only {agree:.0%} of the frames agree with one shared "
            f"correction (the others have errors of their own); the fitted one moves the "
            f"images by {entry.get('effect_px') or float('nan'):.1f} px"
        )
    return entry


def frame_residuals(ev: Sequence[Any], est: Any) -> np.ndarray:
    """Median reprojection residual (px) of each frame's evidence after the world correction
    ``est`` (a ``RegistrationEstimate``; identity when it failed)."""
    out = []
    for e in ev:
        pose = e.world_from_cam
        if est.success and est.corrected_world_from_world is not None:
            pose = est.correct(e.world_from_cam)
        xc = (e.pts3d - pose[:3, 3]) @ pose[:3, :3]
        ok = xc[:, 2] > 1e-9
        proj = (xc[ok] @ e.K.T)[:, :2] / xc[ok, 2:3]
        d = np.linalg.norm(proj - e.pts2d[ok], axis=1)
        out.append(float(np.median(d)) if len(d) else float("inf"))
    return np.asarray(out)


def consistent_frames(
    ev: Sequence[Any], fit: Any, floor_px: float, ceiling_px: float, rounds: int = 3
) -> tuple[list, list[str]]:
    """The frames whose evidence agrees with one shared correction, and the ids of the others.

    A frame with its own pose error (bad frames among good ones) keeps a large residual after
    the correction that fits the others; pooling it would bias the shared estimate. A frame is
    left out when its median residual exceeds the frames' median + 3 robust standard
    deviations, clamped to [``floor_px``, ``ceiling_px``]; the correction is refitted on the
    kept frames (``fit(frames) -> RegistrationEstimate``) and the test repeated."""
    kept = list(ev)
    for _ in range(rounds):
        res = frame_residuals(ev, fit(kept))
        finite = res[np.isfinite(res)]
        if len(finite) < 3:
            return list(ev), []
        med = float(np.median(finite))
        spread = 3.0 * 1.4826 * float(np.median(np.abs(finite - med)))
        cut = min(max(med + spread, floor_px), max(ceiling_px, floor_px))
        new = [e for e, r in zip(ev, res, strict=True) if r <= cut]
        if len(new) < 3 or [e.frame_id for e in new] == [e.frame_id for e in kept]:
            break
        kept = new
    ids = {e.frame_id for e in kept}
    return kept, [e.frame_id for e in ev if e.frame_id not in ids]


def _without(cals: Mapping[str, CameraCalibration], e: Any) -> Any:
    """The frame's evidence with its camera's calibration error removed (if one is known)."""
    return cals[e.camera_id].remove(e) if e.camera_id in cals else e


def run_shared_checks(measurements: Sequence[FrameMeasurement], config: RunConfig) -> SharedChecks:
    """All run-level checks on the measurements (in trajectory order)."""
    from pgt_check.geometry.shared_errors import (
        estimate_calibration,
        estimate_drift,
        estimate_registration,
    )

    thr = shared_threshold(measurements, config)
    frame_thr = (
        float(np.median([config.verdict.threshold_for(m.width, m.height) for m in measurements]))
        if measurements
        else thr
    )
    ev = frame_evidence(measurements)
    # frames with an error of their own are left out of the pooled fits
    all_ev = ev
    ev, left_out = consistent_frames(
        ev, lambda fr: estimate_registration(fr, n_bootstrap=0), 0.5 * frame_thr, 0.5 * frame_thr
    )
    if left_out:
        logger.info(
            "run-level checks: %d frames with their own error left out (%s)",
            len(left_out),
            ", ".join(left_out[:5]),
        )
    v = config.verdict
    trans = v.calibration_translation
    calib, cals = {}, {}
    for cam_id, est in estimate_calibration(ev, calibration_translation=trans).items():
        calib[cam_id] = _calibration_entry(est, thr, frame_thr)
        cal = CameraCalibration.from_estimate(est)
        if cal is not None:
            cals[cam_id] = cal
    for cam_id in sorted({m.camera_id for m in measurements} - set(calib)):
        calib[cam_id] = {
            "status": NOT_CHECKED,
            "reason": "no_absolute_evidence",
            "message": "calibration not checked: no absolute evidence",
        }
    mode = "auto"
    intrinsics = {m.camera_id: m.intrinsics for m in measurements if m.intrinsics}
    change: dict[str, dict[str, Any]] = {}
    if v.calibration_from:
        # a calibration known from a trusted run (same cameras): removed before judging, so
        # this run's own shared error cannot be taken for calibration; what is left of the
        # calibration is this camera's change since that run
        cals = trusted_calibration(v.calibration_from, sorted(intrinsics))
        rest = [_without(cals, e) for e in ev]
        # calibration only: the change is what the trusted calibration leaves unexplained (a
        # joint fit would trade part of it against a world correction, and re-split the same
        # run's calibration differently)
        for cam_id, est in estimate_calibration(
            rest, registration="none", calibration_translation=trans
        ).items():
            if cam_id:
                change[cam_id] = _calibration_change_entry(est, thr)
    homs, frame_homs = frame_homographies(
        cals, all_ev, intrinsics, {m.frame_id: m.camera_id for m in measurements}
    )
    if (v.remove_calibration or v.calibration_from) and cals:
        # the user states that the shared camera-frame error is calibration: the evidence is
        # corrected by it, and registration / drift are judged on what remains
        ev, all_ev = [_without(cals, e) for e in ev], [_without(cals, e) for e in all_ev]
        mode = "none"
    kw = {"calibration": mode, "calibration_translation": trans}
    reg, sim = (
        _shared_or_not(
            _registration_entry(est := estimate_registration(ev, similarity=s, **kw), thr, kind),
            frame_residuals(ev, est),
            0.5 * frame_thr,
        )
        for s, kind in ((False, "rigid"), (True, "similarity"))
    )
    # drift looks at every frame: a drifting segment is what the consistent frames leave out;
    # frames without evidence of their own are covered by the segment they lie in
    ids = [m.frame_id for m in measurements]
    drift_thr = DRIFT_THRESHOLD_FACTOR * thr
    drift, drift_px, flagged = _drift_entry(
        estimate_drift(all_ev, threshold_px=drift_thr, **kw), ids, drift_thr
    )
    for entry in (reg, sim):
        entry["frames_left_out"] = left_out
    return SharedChecks(
        thr, reg, sim, drift, calib, drift_px, flagged, homs, frozenset(left_out), frame_homs,
        drift_thr, texture_entry(measurements, thr), change,
    )  # fmt: skip
