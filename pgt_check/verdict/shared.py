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

The threshold (``run_checks.threshold_px``; default 0.15 x the per-frame
threshold) is lower than the per-frame one because pooled evidence is far more precise, and
errors every frame shares matter more.
"""

from __future__ import annotations

import logging
from collections.abc import Collection, Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from pgt_check.config import RunConfig
from pgt_check.constants import (  # re-exported: callers and tests use them here
    DRIFT_THRESHOLD_FACTOR,
    MAX_FRAME_EVIDENCE_POINTS,
    MAX_POOLED_POINTS,
    MIN_FRAME_EVIDENCE_POINTS,
    OWN_ERROR_FRACTION,
)
from pgt_check.measure.record import FrameMeasurement
from pgt_check.verdict.calibration import (
    CameraCalibration,
    camera_matrix,
    frame_homographies,
    trusted_calibration,
)
from pgt_check.verdict.shared_entries import (
    calibration_change_entry,
    calibration_entry,
    drift_entry,
    frame_screen_entry,
    registration_entry,
    shared_or_not,
)
from pgt_check.verdict.shared_results import (
    CalibrationCheck,
    DriftCheck,
    FrameScreenCheck,
    RegistrationCheck,
    TextureCheck,
)
from pgt_check.verdict.status import FAILED, INCONCLUSIVE, NOT_CHECKED, PASSED
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
    registration: RegistrationCheck
    similarity: RegistrationCheck
    drift: DriftCheck
    calibration: dict[str, CalibrationCheck]
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
    texture: TextureCheck | None = None
    #: with ``--calibration-from``, per camera id: what is left of the calibration after
    #: removing the trusted run's (``calibration_change_entry``); a FAILED camera's frames FAIL
    calibration_change: dict[str, CalibrationCheck] = field(default_factory=dict)
    #: camera id -> the calibration error the checks took out of the evidence
    #: (``run_checks.removes_calibration``: this run's estimate, or a trusted run's); the
    #: absolute paths are judged, and the per-frame bounds fitted, with it removed
    removed_calibrations: dict[str, CameraCalibration] = field(default_factory=dict)
    #: which frames the pooled fits left out and why (``frame_screen_entry``)
    frame_screen: FrameScreenCheck | None = None

    @property
    def removes_calibration(self) -> bool:
        return bool(self.removed_calibrations)

    def calibration_homography(self, frame_id: str, camera_id: str) -> np.ndarray | None:
        """The calibration error's photo_from_render for this frame (None if not estimated)."""
        h = self.frame_homographies.get(frame_id)
        return self.calibration_homographies.get(camera_id) if h is None else h

    @property
    def registration_status(self) -> str:
        """The worse of the rigid and the similarity check."""
        order = (FAILED, INCONCLUSIVE, NOT_CHECKED, PASSED)
        sts = {self.registration.status, self.similarity.status}
        for s in order:
            if s in sts:
                return s
        return NOT_CHECKED

    def summary(self) -> dict[str, Any]:
        """The summary.json ``shared_errors`` section."""
        return {
            "threshold_px": self.threshold_px,
            "registration": self.registration.to_json(),
            "similarity": self.similarity.to_json(),
            "drift": self.drift.to_json(),
            "calibration": {cam: e.to_json() for cam, e in self.calibration.items()},
            **({"texture": self.texture.to_json()} if self.texture is not None else {}),
            **(
                {"frame_screen": self.frame_screen.to_json()}
                if self.frame_screen is not None
                else {}
            ),
            **(
                {"calibration_change": {cam: e.to_json() for cam, e in self.calibration_change.items()}}
                if self.calibration_change
                else {}
            ),
        }

    def calibration_changed(self, camera_id: str) -> CalibrationCheck | None:
        """The calibration-change entry of this camera when it FAILED (else None)."""
        e = self.calibration_change.get(camera_id)
        return e if e is not None and e.status == FAILED else None


def shared_threshold(measurements: Sequence[FrameMeasurement], config: RunConfig) -> float:
    """The shared-error threshold in photo pixels (median over the frames' image sizes)."""
    rc = config.run_checks
    if rc.threshold_px is not None:
        return float(rc.threshold_px)
    if not measurements:
        return float("nan")
    per_frame = [config.verdict.threshold_for(m.width, m.height) for m in measurements]
    return float(rc.threshold_rel * np.median(per_frame))


def frame_evidence(
    measurements: Sequence[FrameMeasurement], exclude_paths: Collection[str] = (),
) -> list[Any]:
    """The frames that carry absolute evidence, as ``FrameEvidence`` (index = trajectory order),
    each with at most ``MAX_FRAME_EVIDENCE_POINTS`` points (evenly spaced over its sources),
    fewer when the frames together would exceed ``MAX_POOLED_POINTS``. ``exclude_paths``: the
    points of these paths (raw, enhanced, edges) are left out, e.g. a path that this run showed
    cannot tell right from wrong (``verdict.separation``)."""
    from pgt_check.geometry.shared_errors import FrameEvidence

    usable = [
        (i, m) for i, m in enumerate(measurements)
        if m.evidence is not None and m.world_from_cam is not None and m.intrinsics is not None
    ]  # fmt: skip
    cap = max(
        MIN_FRAME_EVIDENCE_POINTS,
        min(MAX_FRAME_EVIDENCE_POINTS, MAX_POOLED_POINTS // max(1, len(usable))),
    )
    out = []
    keep_paths = [p for p in ("raw", "enhanced", "edges") if p not in set(exclude_paths)]
    for i, m in usable:
        wfc = np.asarray(m.world_from_cam, np.float64)
        if exclude_paths:
            pts2d, pts_cam = m.evidence.points_of(keep_paths)
            if not len(pts2d):
                continue
        else:
            pts_cam, pts2d = m.evidence.pts_cam, m.evidence.pts2d
        pts_cam = np.asarray(pts_cam, np.float64).reshape(-1, 3)
        pts2d = np.asarray(pts2d, np.float64).reshape(-1, 2)
        if len(pts2d) > cap:
            keep = np.linspace(0, len(pts2d) - 1, cap).round().astype(int)
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


def _without(cals: Mapping[str, CameraCalibration], e: Any) -> Any:
    """The frame's evidence with its camera's calibration error removed (if one is known)."""
    return cals[e.camera_id].remove(e) if e.camera_id in cals else e


def _calibration_checks(
    ev: Sequence[Any], measurements: Sequence[FrameMeasurement], config: RunConfig,
    thr: float, frame_thr: float,
) -> tuple[dict[str, CalibrationCheck], dict[str, CameraCalibration], dict[str, CalibrationCheck]]:
    """Per camera: the calibration entry, the calibration to remove (this run's estimate, or the
    trusted run's with ``calibration_from``) and, with ``calibration_from``, the change entry."""
    from pgt_check.geometry.shared_errors import CalibrationSettings, estimate_calibration

    v = config.run_checks
    settings = CalibrationSettings(calibration_translation=v.calibration_translation)
    # --remove-calibration: the user asserts the registration, so the shared camera-frame
    # error of this run IS the calibration, whatever the separability test says (a joint fit
    # would hand part of it to a world correction, and the registration check would then fail
    # on the calibration it was told to remove); the ambiguity is reported, never the estimate
    # dropped. Otherwise registration and calibration are told apart where the views allow.
    asserted = bool(v.remove_calibration and not v.calibration_from)
    calib, cals = {}, {}
    for cam_id, est in estimate_calibration(
        ev, settings, registration="none" if asserted else "auto"
    ).items():
        calib[cam_id] = calibration_entry(est, thr, frame_thr, asserted=asserted)
        cal = CameraCalibration.from_estimate(est)
        if cal is not None:
            cals[cam_id] = cal
    for cam_id in sorted({m.camera_id for m in measurements} - set(calib)):
        calib[cam_id] = CalibrationCheck(
            NOT_CHECKED, "no_absolute_evidence", "calibration not checked: no absolute evidence",
            estimated=False,
        )
    change: dict[str, CalibrationCheck] = {}
    if v.calibration_from:
        # a calibration known from a trusted run (same cameras): removed before judging, so
        # this run's own shared error cannot be taken for calibration; what is left of the
        # calibration is this camera's change since that run
        intrinsics = {m.camera_id: m.intrinsics for m in measurements if m.intrinsics}
        cals = trusted_calibration(v.calibration_from, sorted(intrinsics))
        rest = [_without(cals, e) for e in ev]
        # calibration only: the change is what the trusted calibration leaves unexplained (a
        # joint fit would trade part of it against a world correction, and re-split the same
        # run's calibration differently)
        for cam_id, est in estimate_calibration(rest, settings, registration="none").items():
            if cam_id:
                change[cam_id] = calibration_change_entry(est, thr)
    return calib, cals, change


def run_shared_checks(
    measurements: Sequence[FrameMeasurement], config: RunConfig,
    exclude_paths: Collection[str] = (),
) -> SharedChecks:
    """All run-level checks on the measurements (in trajectory order); ``exclude_paths``: paths
    whose points do not enter the pooled fits (``frame_evidence``)."""
    from pgt_check.geometry import shared_errors as se

    thr = shared_threshold(measurements, config)
    frame_thr = (
        float(np.median([config.verdict.threshold_for(m.width, m.height) for m in measurements]))
        if measurements
        else thr
    )
    ev = frame_evidence(measurements, exclude_paths)
    own = OWN_ERROR_FRACTION * frame_thr  # fallback where too few frames to test them
    v = config.run_checks
    trans = v.calibration_translation
    # frames with an error of their own are left out of the pooled fits: a significance test
    # of each frame's own correction against the null spread of all frames (screening.py)
    all_ev = ev
    screen = se.screen_frames(ev, se.FitSettings(n_bootstrap=0, calibration_translation=trans))
    left_out = list(screen.left_out)
    isolated = set(screen.isolated)
    if left_out:
        logger.info(
            "run-level checks: %d of %d frames with their own error left out (%s)",
            len(left_out), len(screen.frames), ", ".join(left_out[:5]),
        )  # fmt: skip
    ev = [e for e in ev if e.frame_id not in set(left_out)]
    intrinsics = {m.camera_id: m.intrinsics for m in measurements if m.intrinsics}
    calib, cals, change = _calibration_checks(ev, measurements, config, thr, frame_thr)
    mode = "auto"
    homs, frame_homs = frame_homographies(
        cals, all_ev, intrinsics, {m.frame_id: m.camera_id for m in measurements}
    )
    if v.removes_calibration and cals:
        # the user states that the shared camera-frame error is calibration: the evidence is
        # corrected by it, and registration / drift are judged on what remains
        ev, all_ev = [_without(cals, e) for e in ev], [_without(cals, e) for e in all_ev]
        mode = "none"
    fit = se.FitSettings(calibration_translation=trans)

    def world_checks(ev_fit: Sequence[Any]) -> tuple[RegistrationCheck, RegistrationCheck]:
        kept = {e.frame_id for e in ev_fit}
        agree = screen.agreement()[[f.frame_id in kept for f in screen.frames]] \
            if screen.tested else None
        return tuple(  # type: ignore[return-value]
            shared_or_not(
                registration_entry(
                    est := se.estimate_registration(ev_fit, fit, similarity=s, calibration=mode),
                    thr, kind,
                ),
                *((agree, 1.0) if agree is not None else (frame_residuals(ev_fit, est), own)),
            )
            for s, kind in ((False, "rigid"), (True, "similarity"))
        )

    reg, sim = world_checks(ev)
    # drift looks at every frame but those with an isolated error of their own: a drifting
    # segment is what the consistent frames leave out (its neighbours share its error);
    # frames without evidence of their own are covered by the segment they lie in
    ids = [m.frame_id for m in measurements]
    drift_thr = DRIFT_THRESHOLD_FACTOR * thr
    drift_set = se.DriftSettings(calibration_translation=trans)
    drift_ev = [e for e in all_ev if e.frame_id not in isolated]
    drift_est = se.estimate_drift(drift_ev, drift_set, threshold_px=drift_thr, calibration=mode)
    drift, drift_px, flagged = drift_entry(drift_est, ids, drift_thr)
    fit_left_out = left_out
    if flagged:
        # a drifting segment is an error of its own: the trajectory's registration is what the
        # frames outside it share (pooled with it, a segment of 40 % of the run pulled the fit
        # by 3 px on bm_mictlantecuhli and failed every frame outside it). Refitted only while
        # the frames outside are the majority of the evidence.
        outside = [e for e in ev if e.frame_id not in flagged]
        refit = world_checks(outside) if 2 * len(outside) > len(ev) else None
        if refit is not None and refit[0].status != NOT_CHECKED:  # else: too few outside
            reg, sim = refit
            fit_left_out = left_out + sorted({e.frame_id for e in ev if e.frame_id in flagged})
    reg, sim = (replace(e, frames_left_out=tuple(fit_left_out)) for e in (reg, sim))
    return SharedChecks(
        thr, reg, sim, drift, calib, drift_px, flagged, homs, frozenset(left_out), frame_homs,
        drift_thr, texture_entry(measurements, thr), change,
        cals if v.removes_calibration else {}, frame_screen_entry(screen),
    )  # fmt: skip
