"""Settings of the run-level estimators, one frozen dataclass each.

``FitSettings`` holds the robust-fit settings the three estimators share and is the settings of
``estimate_registration``; ``CalibrationSettings`` (``estimate_calibration``) differs only in a
default, ``DriftSettings`` (``estimate_drift``) adds the windows and the segment rule. What is
chosen per call (``similarity``, the ``calibration`` / ``registration`` mode, ``scene_depth``,
``threshold_px``) stays an argument of the estimator. Nothing is validated here: the estimators
read the values as they are.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class FitSettings:
    """The robust-fit settings shared by the estimators (``estimate_registration``'s own)."""

    #: bootstrap rounds for the 95 % intervals (0: no intervals)
    n_bootstrap: int = 100
    #: seed of the bootstrap's frame resampling
    seed: int = 0
    #: Cauchy loss scale (px) the robust fit is graduated down to
    loss_scale_px: float = 2.0
    #: inlier threshold (px) on the residual after the fit
    max_error_px: float = 6.0
    #: frames with evidence needed (the interval resamples frames: fewer give too few distinct
    #: resamples, and 3 frames with errors of their own fit a shared similarity closely)
    min_frames: int = 5
    #: points a frame needs to count as a frame with evidence
    min_points_per_frame: int = 6
    #: inliers a successful estimate needs
    min_inliers: int = 30
    #: largest canonical correlation between the world and calibration blocks below which they
    #: are separable (a full synthetic loop gives 0.980, 7-Scenes 0.988-0.990)
    max_correlation: float = 0.985
    #: scale of the BIC-like price of a fit's parameters: a shared error is significant, and a
    #: joint fit adopted in "auto", only when the robust-cost drop exceeds that price
    model_penalty: float = 2.0
    #: world-only and calibration-only fits within this fraction of the larger cost drop
    #: explain the error about equally well (ambiguous attribution)
    ambiguity_margin: float = 0.1
    #: also fit a camera-frame translation per camera (a camera mounted beside the sensor whose
    #: poses are given, e.g. RGB beside depth) where the points' depths differ enough; off by
    #: default: for cameras circling the scene it mimics a world rotation
    calibration_translation: bool = False
    #: test whether the frames pull together (``RegistrationEstimate.coherence_p``; the drift
    #: windows, which compare windows with each other, do not)
    coherence: bool = True


@dataclass(frozen=True)
class CalibrationSettings(FitSettings):
    """``estimate_calibration``'s settings: the shared ones with fewer frames needed."""

    #: frames with evidence needed, overall and per camera
    min_frames: int = 3


@dataclass(frozen=True)
class DriftSettings(FitSettings):
    """``estimate_drift``'s settings: the shared ones plus the windows and the segment rule."""

    #: frames a window grows to hold; the run needs twice as many
    min_frames: int = 5
    #: inliers the reference (global) estimate needs
    min_inliers: int = 12
    #: nominal window length, a fraction of the index span
    window: float = 0.2
    #: window step, a fraction of the window
    step: float = 0.5
    #: inliers of the reference fit a window grows to hold (its own fit needs half as many)
    min_window_inliers: int = 150
    #: points a window grows to hold
    min_points: int = 60
    #: a run of flagged frames is a segment when it spans this many flagged windows ...
    min_segment_windows: int = 2
    #: ... or this many frames (shorter runs are ``rejected_segments``)
    min_segment_frames: int = 3
