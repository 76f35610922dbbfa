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
from typing import Any, cast

import numpy as np

from pgt_check.config.judge import JudgingConfig
from pgt_check.constants import (  # re-exported: callers and tests use them here
    DRIFT_THRESHOLD_FACTOR,
    MAX_FRAME_EVIDENCE_POINTS,
    MAX_POOLED_POINTS,
    MIN_FRAME_EVIDENCE_POINTS,
    OWN_ERROR_FRACTION,
)
from pgt_check.measure.record import FrameMeasurement
from pgt_check.verdict.calibration import CameraCalibration, camera_matrix
from pgt_check.verdict.checks.base import frame_residuals  # re-exported
from pgt_check.verdict.shared_results import (
    CalibrationCheck,
    CameraChecks,
    DriftCheck,
    FrameScreenCheck,
    RegistrationCheck,
    TextureCheck,
)
from pgt_check.verdict.status import FAILED, INCONCLUSIVE, NOT_CHECKED, PASSED

logger = logging.getLogger(__name__)

__all__ = ["DRIFT_THRESHOLD_FACTOR", "MAX_FRAME_EVIDENCE_POINTS", "MAX_POOLED_POINTS",
           "MIN_FRAME_EVIDENCE_POINTS", "OWN_ERROR_FRACTION", "SharedChecks", "frame_evidence",
           "frame_residuals", "run_shared_checks", "shared_threshold"]


@dataclass(frozen=True)
class SharedChecks:
    """Results of the run-level checks: each check's entry by its key (``entries``, in the
    registry's order, ``verdict.checks.CHECKS``; ``summary()`` is the summary.json section) and
    what the verdicts read beside the entries.

    ``drift_px`` / ``drift_flagged``: per frame id, the drift score and whether the frame lies in
    a flagged segment. ``calibration_homographies``: camera id -> (3, 3) photo_from_render of the
    estimated calibration error (for ``--remove-calibration``).
    """

    threshold_px: float
    #: check key -> entry (``verdict.checks``: each has ``to_json``, its summary entry)
    entries: Mapping[str, Any]
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
    #: camera id -> the calibration error the checks took out of the evidence
    #: (``run_checks.removes_calibration``: this run's estimate, or a trusted run's); the
    #: absolute paths are judged, and the per-frame bounds fitted, with it removed
    removed_calibrations: dict[str, CameraCalibration] = field(default_factory=dict)

    def with_entries(self, **entries: Any) -> SharedChecks:
        """These checks with some entries replaced (by key)."""
        return replace(self, entries={**self.entries, **entries})

    # the entries the verdicts and the correction stage read by name
    @property
    def registration(self) -> RegistrationCheck:
        return self.entries.get("registration") or RegistrationCheck()

    @property
    def similarity(self) -> RegistrationCheck:
        return self.entries.get("similarity") or RegistrationCheck(kind="similarity")

    @property
    def drift(self) -> DriftCheck:
        return self.entries.get("drift") or DriftCheck(NOT_CHECKED, "", "")

    @property
    def calibration(self) -> Mapping[str, CalibrationCheck]:
        e = self.entries.get("calibration")
        return e.cameras if e is not None else {}

    @property
    def calibration_change(self) -> Mapping[str, CalibrationCheck]:
        """With ``--calibration-from``, per camera id: what is left of the calibration after
        removing the trusted run's (``calibration_change_entry``); a FAILED camera's frames
        FAIL."""
        e = self.entries.get("calibration_change")
        return e.cameras if e is not None else {}

    @property
    def texture(self) -> TextureCheck | None:
        """Mesh colours against mesh geometry (``texture_entry``; None when not run)."""
        return self.entries.get("texture")

    @property
    def frame_screen(self) -> FrameScreenCheck | None:
        """Which frames the pooled fits left out and why (``frame_screen_entry``)."""
        return self.entries.get("frame_screen")

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
        """The summary.json ``shared_errors`` section: the threshold, then each entry."""
        return {"threshold_px": self.threshold_px,
                **{key: e.to_json() for key, e in self.entries.items()}}

    @classmethod
    def from_summary(cls, d: Mapping[str, Any]) -> SharedChecks:
        """The checks of a summary.json ``shared_errors`` section (``summary``'s form; for
        callers holding a written summary: an older run's, a test's): the registration, drift
        and calibration entries, none of the per-frame values the verdicts read."""
        entries: dict[str, Any] = {
            "registration": RegistrationCheck.from_json(d.get("registration") or {}),
            "similarity": RegistrationCheck.from_json(
                {"kind": "similarity", **(d.get("similarity") or {})}),
            "drift": DriftCheck.from_json(d.get("drift") or {}),
            "calibration": CameraChecks.from_json(d.get("calibration") or {}),
        }
        if d.get("calibration_change"):
            entries["calibration_change"] = CameraChecks.from_json(d["calibration_change"])
        return cls(float(d.get("threshold_px", float("nan"))), entries)

    def calibration_changed(self, camera_id: str) -> CalibrationCheck | None:
        """The calibration-change entry of this camera when it FAILED (else None)."""
        e = self.calibration_change.get(camera_id)
        return e if e is not None and e.status == FAILED else None


def shared_threshold(measurements: Sequence[FrameMeasurement], config: JudgingConfig) -> float:
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
        ev = m.evidence
        assert ev is not None and m.intrinsics is not None  # usable
        if exclude_paths:
            pts2d, pts_cam = ev.points_of(keep_paths)
            if not len(pts2d):
                continue
        else:
            pts_cam, pts2d = ev.pts_cam, ev.pts2d
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


def run_shared_checks(
    measurements: Sequence[FrameMeasurement], config: JudgingConfig,
    exclude_paths: Collection[str] = (),
) -> SharedChecks:
    """All run-level checks (``verdict.checks.CHECKS``, in registry order) on the measurements
    (in trajectory order); ``exclude_paths``: paths whose points do not enter the pooled fits
    (``frame_evidence``)."""
    from pgt_check.verdict.checks import CHECKS, CheckContext

    thr = shared_threshold(measurements, config)
    frame_thr = (
        float(np.median([config.verdict.threshold_for(m.width, m.height) for m in measurements]))
        if measurements
        else thr
    )
    ctx = CheckContext(measurements, config, thr, frame_thr,
                       frame_evidence(measurements, exclude_paths))
    entries = {c.KEY: e for c in CHECKS if (e := c.run(ctx)) is not None}
    drift = cast("DriftCheck | None", entries.get("drift"))  # the drift check's entry
    homs, frame_homs = ctx.homographies
    return SharedChecks(
        thr, entries,
        drift_px=dict(drift.scores) if drift is not None else {},
        drift_flagged=drift.flagged_ids if drift is not None else frozenset(),
        calibration_homographies=homs,
        left_out=frozenset(ctx.left_out),
        frame_homographies=frame_homs,
        drift_threshold_px=DRIFT_THRESHOLD_FACTOR * thr,
        removed_calibrations=(ctx.calibrations.estimates
                              if config.run_checks.removes_calibration else {}),
    )
