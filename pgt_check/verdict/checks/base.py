"""What the run-level checks share: ``CheckContext`` (the pooled evidence, the frames screened
out, the calibration estimated and removed, computed once, when a check first asks) and the
default presentation of an entry (``status_lines``, ``single_row``).

A check module (``pgt_check.verdict.checks``) turns the context into its entry; the entry's
``to_json`` is its summary.json value, the module's ``lines`` / ``table`` read that value back
(so ``pgt-check`` and ``pgt-check report`` print the same from summary.json).
"""

from __future__ import annotations

import logging
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from functools import cached_property
from typing import Any

import numpy as np

from pgt_check.config.judge import JudgingConfig
from pgt_check.constants import OWN_ERROR_FRACTION
from pgt_check.measure.record import FrameMeasurement
from pgt_check.verdict.calibration import (
    CameraCalibration,
    frame_depths,
    frame_homographies,
    trusted_calibration,
    uncovered_share,
    views_of,
)
from pgt_check.verdict.shared_entries import (
    calibration_change_entry,
    calibration_entry,
    trusted_allowance,
)
from pgt_check.verdict.shared_results import CalibrationCheck
from pgt_check.verdict.status import FAILED, FINDING, INCONCLUSIVE, NOT_CHECKED

logger = logging.getLogger(__name__)

__all__ = ["CheckContext", "frame_residuals", "single_row", "status_lines"]

#: the statuses whose message ``pgt-check`` prints (and a texture check without geometric
#: evidence: it says what the run cannot see)
PRINTED = (FAILED, INCONCLUSIVE, FINDING)


def status_lines(entry: Any) -> list[str]:
    """The headline line of one summary entry: its message where it failed, is inconclusive or
    a finding (or no geometric evidence could check it)."""
    if isinstance(entry, dict) and (entry.get("status") in PRINTED
                                    or entry.get("reason") == "no_geometric_evidence"):
        return [str(entry["message"])]
    return []


def single_row(title: str, entry: Any) -> list[tuple[str, Mapping[str, Any]]]:
    """The report table's row of one summary entry: (name, entry)."""
    return [(title, entry)] if isinstance(entry, Mapping) and "status" in entry else []


def camera_rows(title: str, entry: Any) -> list[tuple[str, Mapping[str, Any]]]:
    """The report table's rows of a per-camera entry: one per camera id."""
    if not isinstance(entry, Mapping):
        return []
    return [(f"{title} (camera {cam})", sub) for cam, sub in entry.items()
            if isinstance(sub, Mapping) and "status" in sub]


def camera_lines(entry: Any) -> list[str]:
    """The headline lines of a per-camera entry (``status_lines`` of each camera)."""
    if not isinstance(entry, Mapping):
        return []
    return [line for sub in entry.values() for line in status_lines(sub)]


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


def without(cals: Mapping[str, CameraCalibration], e: Any) -> Any:
    """The frame's evidence with its camera's calibration error removed (if one is known)."""
    return cals[e.camera_id].remove(e) if e.camera_id in cals else e


@dataclass(frozen=True)
class Calibrations:
    """Per camera: the calibration entries, the calibrations to remove (this run's estimate,
    or the trusted run's with ``calibration_from``) and, with ``calibration_from``, the change
    entries."""

    checks: dict[str, CalibrationCheck]
    estimates: dict[str, CameraCalibration]
    change: dict[str, CalibrationCheck] = field(default_factory=dict)
    #: with ``calibration_from``: what the trusted calibrations removed may carry of their own
    #: run's misregistration (px, the largest over this run's cameras; ``trusted_allowance``)
    allowance_px: float = 0.0


@dataclass
class CheckContext:
    """What several run-level checks share, computed once on first use: the thresholds, the
    frames' pooled evidence (``ev``: every frame with absolute evidence, ``pooled``: without
    the frames screened out as having an error of their own), the screening, the calibration
    per camera and the evidence with it removed (``--remove-calibration``)."""

    measurements: Sequence[FrameMeasurement]
    config: JudgingConfig
    #: the shared-error threshold (``shared.shared_threshold``) and the median per-frame one
    threshold_px: float
    frame_threshold_px: float
    #: every frame with absolute evidence (``shared.frame_evidence``), trajectory order
    ev: list[Any]

    @property
    def translation(self) -> bool:
        return self.config.run_checks.calibration_translation

    @cached_property
    def screen(self) -> Any:
        """Frames with an error of their own: a significance test of each frame's own
        correction against the null spread of all frames (``geometry.shared_errors``)."""
        from pgt_check.geometry import shared_errors as se

        screen = se.screen_frames(
            self.ev, se.FitSettings(n_bootstrap=0, calibration_translation=self.translation))
        if screen.left_out:
            logger.info(
                "run-level checks: %d of %d frames with their own error left out (%s)",
                len(screen.left_out), len(screen.frames), ", ".join(list(screen.left_out)[:5]),
            )  # fmt: skip
        return screen

    @cached_property
    def left_out(self) -> tuple[str, ...]:
        return tuple(self.screen.left_out)

    @cached_property
    def pooled(self) -> list[Any]:
        """The evidence without the frames screened out."""
        out = set(self.left_out)
        return [e for e in self.ev if e.frame_id not in out]

    @cached_property
    def calibrations(self) -> Calibrations:
        return _calibration_checks(self.pooled, self.measurements, self.config,
                                   self.threshold_px, self.frame_threshold_px)

    @property
    def removes_calibration(self) -> bool:
        """The evidence is corrected by the calibration before registration and drift."""
        return bool(self.config.run_checks.removes_calibration and self.calibrations.estimates)

    @property
    def allowance_px(self) -> float:
        """What the registration fits cannot attribute: the trusted calibration removed first
        may carry that much of its own run's misregistration (``Calibrations.allowance_px``)."""
        return self.calibrations.allowance_px if self.removes_calibration else 0.0

    @property
    def mode(self) -> str:
        """The registration and drift fits' calibration mode."""
        return "none" if self.removes_calibration else "auto"

    def _removed(self, ev: list[Any]) -> list[Any]:
        cals = self.calibrations.estimates
        return [without(cals, e) for e in ev] if self.removes_calibration else ev

    @cached_property
    def fitted(self) -> list[Any]:
        """The pooled evidence the registration fits see (calibration removed where asked)."""
        return self._removed(self.pooled)

    @cached_property
    def all_fitted(self) -> list[Any]:
        """Every frame's evidence, calibration removed where asked (the drift check's)."""
        return self._removed(self.ev)

    @cached_property
    def homographies(self) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]]:
        """The calibration error's photo_from_render per camera and per frame."""
        intrinsics = {m.camera_id: m.intrinsics for m in self.measurements if m.intrinsics}
        return frame_homographies(self.calibrations.estimates, self.ev, intrinsics,
                                  {m.frame_id: m.camera_id for m in self.measurements})

    @cached_property
    def agreement(self) -> tuple[Any, float] | None:
        """The frames' agreement with the shared model where the screening tested them (and
        the tolerance), else None (each fit's residuals decide)."""
        return (self.screen.agreement(), 1.0) if self.screen.tested else None

    def agreement_of(self, ev: Sequence[Any]) -> tuple[Any, float] | None:
        """``agreement`` of the frames a fit used (``ev``): the frames left out disagree by
        construction and do not count."""
        if self.agreement is None:
            return None
        used = {e.frame_id for e in ev}
        mask = np.array([f.frame_id in used for f in self.screen.frames], bool)
        return self.agreement[0][mask], self.agreement[1]

    @cached_property
    def drift(self) -> tuple[Any, dict[str, float], frozenset[str]]:
        """The drift check's (entry, per-frame scores, flagged frame ids): windows along the
        trajectory on every frame's evidence but those with an isolated error of their own
        (a drifting segment's neighbours share its error)."""
        from pgt_check.constants import DRIFT_THRESHOLD_FACTOR
        from pgt_check.geometry import shared_errors as se
        from pgt_check.verdict.shared_entries import drift_entry

        thr = DRIFT_THRESHOLD_FACTOR * self.threshold_px
        isolated = set(self.screen.isolated)
        settings = se.DriftSettings(calibration_translation=self.translation)
        est = se.estimate_drift(
            [e for e in self.all_fitted if e.frame_id not in isolated], settings,
            threshold_px=thr, calibration=self.mode,
        )  # fmt: skip
        if not est.success and est.reason == "too_few_frames" and isolated:
            # short runs (the castle's 10 photos): leaving the isolated frames out left too few
            # to check; a drift's growing end can look isolated, so all frames are checked
            est = se.estimate_drift(self.all_fitted, settings, threshold_px=thr,
                                    calibration=self.mode)
        return drift_entry(est, [m.frame_id for m in self.measurements], thr)

    @cached_property
    def outside_drift(self) -> list[Any] | None:
        """The registration fits' evidence without a flagged drifting segment (None when none
        was flagged or the frames outside it are not the majority of the evidence): the segment
        is an error of its own, and the registration is what the frames outside it share
        (pooled with it, a segment of 40 % of the run pulled the fit by 3 px on
        bm_mictlantecuhli and failed every frame outside it)."""
        flagged = self.drift[2]
        if not flagged:
            return None
        outside = [e for e in self.fitted if e.frame_id not in flagged]
        return outside if 2 * len(outside) > len(self.fitted) else None

    @property
    def own_error_px(self) -> float:
        """Fallback tolerance where too few frames to test them."""
        return OWN_ERROR_FRACTION * self.frame_threshold_px


def _calibration_checks(
    ev: Sequence[Any], measurements: Sequence[FrameMeasurement], config: JudgingConfig,
    thr: float, frame_thr: float,
) -> Calibrations:
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
        if calib[cam_id].estimated:
            views = views_of([e.world_from_cam for e in ev if e.camera_id == cam_id])
            calib[cam_id] = replace(calib[cam_id], views=np.round(views, 4).tolist())
        cal = CameraCalibration.from_estimate(est)
        if cal is not None:
            cals[cam_id] = cal
    for cam_id in sorted({m.camera_id for m in measurements} - set(calib)):
        calib[cam_id] = CalibrationCheck(
            NOT_CHECKED, "no_absolute_evidence", "calibration not checked: no absolute evidence",
            estimated=False,
        )
    change: dict[str, CalibrationCheck] = {}
    allowance = 0.0
    if v.calibration_from:
        # a calibration known from a trusted run (same cameras): removed before judging, so
        # this run's own shared error cannot be taken for calibration; what is left of the
        # calibration is this camera's change since that run
        intrinsics = {m.camera_id: m.intrinsics for m in measurements if m.intrinsics}
        cals = trusted_calibration(v.calibration_from, sorted(intrinsics))
        rest = [without(cals, e) for e in ev]
        zs = list(frame_depths(ev).values())
        depth = float(np.median(zs)) if zs else math.nan
        allowed = {
            c: trusted_allowance(cal, thr, uncovered_share(
                cal.views, views_of([e.world_from_cam for e in ev if e.camera_id == c]), depth))
            for c, cal in cals.items()
        } if math.isfinite(depth) else {}
        allowance = max([allowed.get(c, 0.0) for c in intrinsics], default=0.0)
        # calibration only: the change is what the trusted calibration leaves unexplained (a
        # joint fit would trade part of it against a world correction, and re-split the same
        # run's calibration differently)
        for cam_id, est in estimate_calibration(rest, settings, registration="none").items():
            if cam_id:
                trusted = cals.get(cam_id)
                change[cam_id] = calibration_change_entry(
                    est, thr, trusted is None or trusted.separable, allowed.get(cam_id, 0.0)
                )
    return Calibrations(calib, cals, change, allowance)

