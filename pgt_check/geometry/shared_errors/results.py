"""Result types of the shared-error estimators (frozen dataclasses with ``to_json``)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

_CI = tuple[float, float]
_NAN_CI: _CI = (float("nan"), float("nan"))


def _exceeds(est: RegistrationEstimate | CalibrationEstimate, threshold_px: float) -> bool:
    """The estimate succeeded and the lower bound of its pixel effect (the effect itself when
    there is no interval) exceeds ``threshold_px``."""
    if not est.success:
        return False
    low = est.effect_px_ci[0]
    return bool((low if np.isfinite(low) else est.effect_px) > threshold_px)


@dataclass(frozen=True, eq=False)
class RegistrationEstimate:
    """One world correction for the whole trajectory (or one drift window).

    corrected_world_from_world: (4, 4) rigid or similarity; corrected pose = it @ world_from_cam
    (use ``correct`` to get a rigid pose back for a similarity). Angles in degrees, translation
    in scene units (displacement of the camera centroid), ``effect_px`` the median over frames of
    the mean image displacement of the frame's inlier points when the correction is applied.
    ``*_ci``: 95 % bootstrap intervals over frames.
    """

    success: bool
    reason: str  # "" on success
    corrected_world_from_world: np.ndarray | None = None
    angle_deg: float = float("nan")
    angle_deg_ci: _CI = _NAN_CI
    translation: float = float("nan")
    translation_ci: _CI = _NAN_CI
    translation_frac: float = float("nan")  # translation / median scene depth
    translation_frac_ci: _CI = _NAN_CI
    scale: float = 1.0
    scale_ci: _CI = (1.0, 1.0)
    effect_px: float = float("nan")
    effect_px_ci: _CI = _NAN_CI
    effect_px_per_frame: np.ndarray = field(default_factory=lambda: np.zeros(0))
    frame_ids: tuple[str, ...] = ()
    median_scene_depth: float = float("nan")
    n_frames: int = 0
    n_points: int = 0
    n_inliers: int = 0
    residual_median_before: float = float("nan")  # px, over the final inliers
    residual_median_after: float = float("nan")
    similarity: bool = False
    calibration_fitted: bool = False  # per-camera calibration fitted jointly as nuisance
    ambiguous_with_calibration: bool = False  # not separable: may be a calibration error
    max_correlation: float = float("nan")  # largest canonical corr. world vs calibration
    ambiguity: str = ""  # why it is ambiguous ("" when not)
    gain_world_only: float = float("nan")  # robust-cost drop of the world-only fit
    gain_calibration_only: float = float("nan")  # robust-cost drop of the calibration-only fit
    #: p-value of "no shared world error, only the frames' own" (``solver._coherence_p``, a
    #: sign-flip test over frames; NaN: not tested)
    coherence_p: float = float("nan")

    def exceeds(self, threshold_px: float) -> bool:
        """True when the lower 95 % bound of the pixel effect exceeds ``threshold_px``."""
        return _exceeds(self, threshold_px)

    def correct(self, world_from_cam: np.ndarray) -> np.ndarray:
        """Apply the correction to one (4, 4) pose; returns a rigid (4, 4) pose."""
        if self.corrected_world_from_world is None:
            raise ValueError(f"no correction ({self.reason})")
        from pgt_check.geometry.transforms import move_pose

        return move_pose(world_from_cam, self.corrected_world_from_world)

    def to_json(self) -> dict:
        return _to_json(self)


@dataclass(frozen=True, eq=False)
class CalibrationEstimate:
    """Shared camera-frame error of one camera (all its frames).

    rotation: (3, 3) ``true_cam_from_checked_cam`` (x_true = rotation @ x_checked +
    translation): the camera-to-rig rotation error; ``rotvec_deg`` its rotation vector (x, y, z = roll) in degrees.
    ``principal_point_shift_px``: the equivalent principal-point shift at the image centre.
    ``focal_scale``: observed focal / given focal. ``effect_px``: median over frames of the mean
    image displacement of the frame's points. ``separable``: False when the error cannot be told
    apart from a world registration error (then this is a calibration-only fit and ``ambiguity``
    says why: inseparable parameter blocks, or world-only and calibration-only fits that explain
    the shared error about equally well).
    """

    success: bool
    reason: str
    camera_id: str
    rotation: np.ndarray | None = None
    rotvec_deg: np.ndarray = field(default_factory=lambda: np.full(3, np.nan))
    rotvec_deg_ci: np.ndarray = field(default_factory=lambda: np.full((3, 2), np.nan))
    equivalent_rotation_deg: float = float("nan")
    equivalent_rotation_deg_ci: _CI = _NAN_CI
    principal_point_shift_px: np.ndarray = field(default_factory=lambda: np.full(2, np.nan))
    principal_point_shift_px_ci: np.ndarray = field(default_factory=lambda: np.full((2, 2), np.nan))
    roll_deg: float = float("nan")
    roll_deg_ci: _CI = _NAN_CI
    focal_scale: float = float("nan")
    focal_scale_ci: _CI = _NAN_CI
    #: (3,) camera-frame translation of ``true_cam_from_checked_cam`` (x_true = rotation @
    #: x_checked + translation), scene units; fitted only where the points' depths differ
    #: enough (``translation_fitted``), else zero
    translation: np.ndarray = field(default_factory=lambda: np.zeros(3))
    translation_ci: np.ndarray = field(default_factory=lambda: np.full((3, 2), np.nan))
    translation_fitted: bool = False
    effect_px: float = float("nan")
    effect_px_ci: _CI = _NAN_CI
    n_frames: int = 0
    n_points: int = 0
    n_inliers: int = 0
    separable: bool = True
    max_correlation: float = float("nan")
    registration_fitted: bool = False  # world correction fitted jointly
    ambiguity: str = ""  # why it is not separable ("" when it is)
    gain_world_only: float = float("nan")  # robust-cost drop of the world-only fit
    gain_calibration_only: float = float("nan")  # robust-cost drop of the calibration-only fit

    def exceeds(self, threshold_px: float) -> bool:
        """True when the lower 95 % bound of the pixel effect exceeds ``threshold_px``."""
        return _exceeds(self, threshold_px)

    def to_json(self) -> dict:
        return _to_json(self)


@dataclass(frozen=True, eq=False)
class DriftWindow:
    """A window ``[start, stop)`` of trajectory indices and its correction relative to the
    reference registration (angle, translation, pixel effect with 95 % CIs that include the
    reference's uncertainty); ``flagged`` when the lower bound of the effect exceeds the
    threshold."""

    start: int
    stop: int
    estimate: RegistrationEstimate
    flagged: bool


@dataclass(frozen=True, eq=False)
class DriftEstimate:
    """Windowed corrections along the trajectory relative to the reference registration.

    frame_score_px / frame_score_low_px: (F,) per-frame drift score (pixel effect of the local
    correction, and its lower 95 % bound, interpolated between window centres) in the order of
    ``frame_ids`` (sorted by index). ``segments``: flagged runs as (first index, last index);
    ``rejected_segments``: runs above the threshold too short to be reported (noise).
    """

    success: bool
    reason: str
    reference: RegistrationEstimate | None = None
    windows: tuple[DriftWindow, ...] = ()
    frame_ids: tuple[str, ...] = ()
    frame_index: np.ndarray = field(default_factory=lambda: np.zeros(0, int))
    frame_score_px: np.ndarray = field(default_factory=lambda: np.zeros(0))
    frame_score_low_px: np.ndarray = field(default_factory=lambda: np.zeros(0))
    frame_flagged: np.ndarray = field(default_factory=lambda: np.zeros(0, bool))
    segments: tuple[tuple[int, int], ...] = ()
    rejected_segments: tuple[tuple[int, int], ...] = ()
    threshold_px: float = float("nan")

    def to_json(self) -> dict:
        return _to_json(self)


def _to_json(obj) -> dict:
    out = {}
    for k, v in obj.__dict__.items():
        if isinstance(v, np.ndarray):
            out[k] = np.round(v.astype(np.float64), 6).tolist() if v.dtype != bool else v.tolist()
        elif isinstance(v, RegistrationEstimate | DriftWindow):
            out[k] = _to_json(v)
        elif isinstance(v, tuple) and v and isinstance(v[0], DriftWindow):
            out[k] = [_to_json(w) for w in v]
        elif isinstance(v, float | np.floating):
            out[k] = None if not np.isfinite(v) else round(float(v), 6)
        elif isinstance(v, tuple):
            out[k] = [(None if isinstance(x, float) and not np.isfinite(x) else x) for x in v]
        else:
            out[k] = v
    return out
