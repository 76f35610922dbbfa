"""The typed entries of the run-level checks (``verdict.shared``): what ``SharedChecks`` keeps and
the verdicts and the correction step read by attribute. Each has ``to_json``, its summary.json
``shared_errors`` entry key for key as it is written (the summary is the one place where the
checks become dicts; ``verdict.shared_entries`` builds the entries from the typed estimates of
``geometry.shared_errors``).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import asdict, dataclass, field
from typing import Any

from pgt_check.verdict.status import NOT_CHECKED

__all__ = ["CalibrationCheck", "CameraChecks", "DriftCheck", "DriftFrame", "FrameScreenCheck", "LeftOutFrame",
           "RegistrationCheck", "Sensitivity", "TextureCheck"]


@dataclass(frozen=True)
class Sensitivity:
    """What a world rotation / translation does to the images (the shared detection limit):
    px per degree and per scene unit (``verdict.frame_bounds.world_sensitivity``)."""

    px_per_deg: float
    px_per_unit: float

    def to_json(self) -> dict[str, float]:
        """The summary's ``registration.sensitivity``."""
        return {"px_per_deg": self.px_per_deg, "px_per_unit": self.px_per_unit}


@dataclass(frozen=True)
class RegistrationCheck:
    """The rigid or similarity registration check (``shared_entries.registration_entry``).

    Sizes are None where not finite (not measured), intervals ``[lo, hi]`` (95 %) or None;
    ``corrected_world_from_world``: the (4, 4) correction as nested lists (None when the fit
    failed). The fields after ``message`` are added by later steps and left out of the summary
    while None: ``frames_agreeing`` (``shared_or_not``), ``frames_left_out``
    (``run_shared_checks``), ``sensitivity`` (``judge_run``, rigid entry), ``refinement`` (the
    correction step's record, ``correct.registration_result``)."""

    status: str = NOT_CHECKED
    reason: str = ""
    kind: str = "rigid"  # or "similarity"
    angle_deg: float | None = None
    angle_deg_ci: list[float] | None = None
    translation: float | None = None
    translation_ci: list[float] | None = None
    translation_rel_depth: float | None = None
    translation_rel_depth_ci: list[float] | None = None
    scale: float | None = None
    scale_ci: list[float] | None = None
    effect_px: float | None = None
    effect_px_ci: list[float] | None = None
    n_frames: int = 0
    n_points: int = 0
    n_inliers: int = 0
    ambiguous_with_calibration: bool = False
    corrected_world_from_world: list[list[float]] | None = None
    #: sign-flip p-value of "the frames' own errors, no shared one" (None: not tested)
    coherence_p: float | None = None
    message: str = ""
    #: share of the frames whose residual agrees with the correction
    frames_agreeing: float | None = None
    #: frames with an error of their own, left out of the pooled fit
    frames_left_out: tuple[str, ...] | None = None
    sensitivity: Sensitivity | None = None
    #: the summary's ``refinement`` block (first pass, rounds, why they stopped)
    refinement: Mapping[str, Any] | None = None
    #: px above the threshold this check allowed for what a non-separable trusted calibration
    #: may carry (``shared_entries.trusted_allowance``): FAILED only above threshold + this
    allowance_px: float | None = None

    def to_json(self) -> dict[str, Any]:
        """The summary.json entry (``shared_errors.registration`` / ``.similarity``)."""
        out: dict[str, Any] = {
            "status": self.status,
            "reason": self.reason,
            "kind": self.kind,
            "angle_deg": self.angle_deg,
            "angle_deg_ci": self.angle_deg_ci,
            "translation": self.translation,
            "translation_ci": self.translation_ci,
            "translation_rel_depth": self.translation_rel_depth,
            "translation_rel_depth_ci": self.translation_rel_depth_ci,
            "scale": self.scale,
            "scale_ci": self.scale_ci,
            "effect_px": self.effect_px,
            "effect_px_ci": self.effect_px_ci,
            "n_frames": self.n_frames,
            "n_points": self.n_points,
            "n_inliers": self.n_inliers,
            "ambiguous_with_calibration": self.ambiguous_with_calibration,
            "corrected_world_from_world": self.corrected_world_from_world,
            "coherence_p": self.coherence_p,
            "message": self.message,
        }
        if self.frames_agreeing is not None:
            out["frames_agreeing"] = self.frames_agreeing
        if self.frames_left_out is not None:
            out["frames_left_out"] = list(self.frames_left_out)
        if self.sensitivity is not None:
            out["sensitivity"] = self.sensitivity.to_json()
        if self.refinement is not None:
            out["refinement"] = dict(self.refinement)
        if self.allowance_px is not None:
            out["allowance_px"] = self.allowance_px
        return out

    @classmethod
    def from_json(cls, d: Mapping[str, Any]) -> RegistrationCheck:
        """The entry of a summary section (``to_json``'s form; for callers that hold the
        summary, not the ``SharedChecks``); keys it lacks keep their defaults."""
        names = cls.__dataclass_fields__
        kw = {k: v for k, v in d.items() if k in names}
        if kw.get("frames_left_out") is not None:
            kw["frames_left_out"] = tuple(kw["frames_left_out"])
        if isinstance(kw.get("sensitivity"), Mapping):
            kw["sensitivity"] = Sensitivity(**kw["sensitivity"])
        return cls(**kw)


@dataclass(frozen=True)
class DriftFrame:
    """One frame's drift score (``shared_entries.drift_coverage``): its trajectory ``index``,
    the score and its lower 95 % bound (px; None where not finite), whether it lies in a flagged
    segment and whether the score is its own (else interpolated between frames with evidence)."""

    frame_id: str
    index: int
    effect_px: float | None
    lo_px: float | None
    flagged: bool
    own_evidence: bool


@dataclass(frozen=True)
class DriftCheck:
    """The drift check (``shared_entries.drift_entry``): flagged ``segments`` as (first, last)
    frame ids, the windows fitted, each frame's score. A check that did not run
    (``NOT_CHECKED``) has only its status, reason and message."""

    status: str
    reason: str
    message: str
    threshold_px: float = float("nan")
    segments: tuple[tuple[str, str], ...] = ()
    n_windows: int = 0
    per_frame: tuple[DriftFrame, ...] = ()
    #: each frame's drift score (px) and the frames in flagged segments (not in the summary
    #: entry: ``SharedChecks.drift_px`` / ``drift_flagged`` hold them for the verdicts)
    scores: Mapping[str, float] = field(default_factory=dict, compare=False)
    flagged_ids: frozenset[str] = frozenset()

    def to_json(self) -> dict[str, Any]:
        """The summary.json entry (``shared_errors.drift``)."""
        if self.status == NOT_CHECKED:
            return {"status": self.status, "reason": self.reason, "message": self.message}
        return {
            "status": self.status,
            "reason": self.reason,
            "threshold_px": self.threshold_px,
            "segments": [list(s) for s in self.segments],
            "n_windows": self.n_windows,
            "per_frame": [asdict(f) for f in self.per_frame],
            "message": self.message,
        }

    @classmethod
    def from_json(cls, d: Mapping[str, Any]) -> DriftCheck:
        """The entry of a summary section (``to_json``'s form); missing keys keep defaults."""
        return cls(
            str(d.get("status", NOT_CHECKED)), str(d.get("reason", "")),
            str(d.get("message", "")), float(d.get("threshold_px", float("nan"))),
            tuple((str(a), str(b)) for a, b in d.get("segments") or ()),
            int(d.get("n_windows", 0)),
            tuple(_drift_frame(f) for f in d.get("per_frame") or ()),
        )  # fmt: skip


def _drift_frame(f: Mapping[str, Any]) -> DriftFrame:
    """A ``per_frame`` item of a drift entry; keys an older or hand-made summary lacks get
    their defaults (no score, not flagged, evidence of its own)."""
    return DriftFrame(
        str(f.get("frame_id", "")), int(f.get("index", 0)), f.get("effect_px"), f.get("lo_px"),
        bool(f.get("flagged", False)), bool(f.get("own_evidence", True)),
    )


@dataclass(frozen=True)
class CalibrationCheck:
    """The calibration check of one camera (``shared_entries.calibration_entry``; also the
    ``--calibration-from`` change entry). ``rotation``: (3, 3) ``true_cam_from_checked_cam`` as
    nested lists; ``translation`` / ``translation_ci`` only where a camera-frame translation
    was fitted. ``estimated`` False: no estimate for this camera at all (no absolute evidence);
    its entry has only status, reason and message."""

    status: str
    reason: str
    message: str = ""
    effect_px: float | None = None
    effect_px_ci: list[float] | None = None
    principal_point_shift_px: list[float] | None = None
    rotation_deg: float | None = None
    rotation_deg_ci: list[float] | None = None
    roll_deg: float | None = None
    focal_scale: float | None = None
    focal_scale_ci: list[float] | None = None
    n_frames: int = 0
    separable_from_registration: bool = True
    rotation: list[list[float]] | None = None
    translation: list[float] | None = None
    translation_ci: list[list[float] | None] | None = None
    estimated: bool = True
    #: the views the estimate rests on: per frame its camera centre and optical axis in world
    #: coordinates (cx, cy, cz, ax, ay, az); a run that removes this calibration
    #: (``--calibration-from``) sees which of its views these cover (``verdict.calibration``)
    views: list[list[float]] | None = None
    #: the calibration change only: px above the threshold allowed for what a non-separable
    #: trusted calibration may carry (``shared_entries.trusted_allowance``)
    allowance_px: float | None = None

    def to_json(self) -> dict[str, Any]:
        """The summary.json entry (``shared_errors.calibration[camera]``)."""
        if not self.estimated:
            return {"status": self.status, "reason": self.reason, "message": self.message}
        return {
            "status": self.status,
            "reason": self.reason,
            "effect_px": self.effect_px,
            "effect_px_ci": self.effect_px_ci,
            "principal_point_shift_px": self.principal_point_shift_px,
            "rotation_deg": self.rotation_deg,
            "rotation_deg_ci": self.rotation_deg_ci,
            "roll_deg": self.roll_deg,
            "focal_scale": self.focal_scale,
            "focal_scale_ci": self.focal_scale_ci,
            "n_frames": self.n_frames,
            "separable_from_registration": self.separable_from_registration,
            "rotation": self.rotation,
            "translation": self.translation,
            "translation_ci": self.translation_ci,
            "message": self.message,
            **({"views": self.views} if self.views is not None else {}),
            **({"allowance_px": self.allowance_px} if self.allowance_px is not None else {}),
        }

    @classmethod
    def from_json(cls, d: Mapping[str, Any]) -> CalibrationCheck:
        """The entry of a summary section (``to_json``'s form); an entry with only status,
        reason and message is one without an estimate."""
        names = cls.__dataclass_fields__
        kw = {k: v for k, v in d.items() if k in names}
        kw.setdefault("status", NOT_CHECKED)
        kw.setdefault("reason", "")
        kw.setdefault("estimated", bool(set(kw) - {"status", "reason", "message"}))
        return cls(**kw)


@dataclass(frozen=True)
class CameraChecks:
    """A check given per camera id (calibration, calibration change): camera id -> its
    ``CalibrationCheck``; the summary entry maps camera ids to their entries."""

    cameras: Mapping[str, CalibrationCheck] = field(default_factory=dict)

    def to_json(self) -> dict[str, Any]:
        return {cam: e.to_json() for cam, e in self.cameras.items()}

    @classmethod
    def from_json(cls, d: Mapping[str, Any]) -> CameraChecks:
        return cls({str(k): CalibrationCheck.from_json(v) for k, v in d.items()
                    if isinstance(v, Mapping)})


@dataclass(frozen=True)
class TextureCheck:
    """Mesh colours against mesh geometry (``verdict.texture.texture_entry``): status, why not
    checked, the photos' offset of the texture matches from the geometric edges (px), its size
    with a 95 % interval, the frames it rests on and the message. Informational."""

    status: str
    reason: str
    n_frames: int
    message: str
    offset_px: tuple[float, float] | None = None
    effect_px: float | None = None
    effect_px_ci: tuple[float, float] | None = None

    def to_json(self) -> dict[str, Any]:
        """The summary's ``shared_errors.texture``."""
        if self.offset_px is None:
            return {"status": self.status, "reason": self.reason, "n_frames": self.n_frames,
                    "message": self.message}
        return {"status": self.status, "reason": self.reason,
                "offset_px": list(self.offset_px), "effect_px": self.effect_px,
                "effect_px_ci": list(self.effect_px_ci or ()), "n_frames": self.n_frames,
                "message": self.message}


@dataclass(frozen=True)
class LeftOutFrame:
    """One frame left out of the pooled fits (``shared_entries.frame_screen_entry``): the image
    effect of its own correction (px), its test statistic over the cut (> 1: significant), and
    whether its neighbours share the error (then it stays in the drift check's evidence)."""

    frame_id: str
    own_error_px: float
    statistic_over_cut: float
    shared_with_neighbours: bool


@dataclass(frozen=True)
class FrameScreenCheck:
    """Which frames the run-level fits left out, and why (``shared_entries.frame_screen_entry``;
    the rule: ``geometry.shared_errors.screening``). ``finding`` when frames were left out,
    ``passed`` when every tested frame agrees with the shared model, ``not_checked`` when too
    few frames carry evidence to test them."""

    status: str
    reason: str
    message: str
    n_tested: int = 0
    n_left_out: int = 0
    #: the null's scale estimated from the frames (variance inflation of the Wald statistic)
    inflation: float | None = None
    #: the cut on the Wald statistic: inflation x ``chi2_quantile``
    cut: float | None = None
    alpha: float | None = None
    #: degrees of freedom of the null fitted to the frames, and its 1 - alpha quantile
    dof: float | None = None
    chi2_quantile: float | None = None
    rounds: int = 0
    majority_kept: bool = False
    left_out: tuple[LeftOutFrame, ...] = ()
    #: the cut on a frame's own image effect (px), its null fitted to the frames' effects
    effect_cut_px: float | None = None

    def to_json(self) -> dict[str, Any]:
        """The summary.json entry (``shared_errors.frame_screen``)."""
        return {
            "status": self.status,
            "reason": self.reason,
            "n_tested": self.n_tested,
            "n_left_out": self.n_left_out,
            "inflation": self.inflation,
            "cut": self.cut,
            "alpha": self.alpha,
            "dof": self.dof,
            "chi2_quantile": self.chi2_quantile,
            "effect_cut_px": self.effect_cut_px,
            "rounds": self.rounds,
            "majority_kept": self.majority_kept,
            "left_out": [asdict(f) for f in self.left_out],
            "message": self.message,
        }
