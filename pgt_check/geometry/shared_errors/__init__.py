"""Run-level shared-error estimators: registration, drift and calibration from pooled evidence.

Per-frame checks cannot see an error that all frames share (see ``docs/evidence.md``). Here the
absolute evidence of many frames is pooled: each frame contributes 2D-3D correspondences (photo
keypoint in photo pixels <-> world point from the render depth, ``pnp.lift_keypoints``), and one
small model of the shared error is fitted to all of them at once.

Observation model for point ``X`` seen in frame ``i`` of camera ``g``::

    u = pi(K_i * zoom_g, R_g @ cam_from_world_i @ D(X)),   D = corrected_world_from_world^-1

* ``D`` (world, about the camera centroid ``c``): ``D(X) = sigma Q (X - c) + c + tau``; rigid
  (``sigma = 1``) or similarity. The reported correction is its inverse ``C``: the corrected pose
  of frame ``i`` is ``C @ world_from_cam_i`` (centre mapped by ``C``, rotation ``R_C R_i``).
* ``R_g, zoom_g`` (camera frame, per ``camera_id``): a camera-to-rig rotation and a focal scale.
  A rotation about the camera x/y axes is the physical form of a principal-point shift
  (``dx ~ fx * ry``, ``dy ~ -fy * rx``, exact at the image centre, keystone at the edges) and
  the rotation about z is the roll. The rotation form is used because the real case (the RGB
  camera of 7-Scenes sits rotated against the depth camera whose poses are given) is a rotation.

Fitting (``solver``): Gauss-Newton / IRLS with analytic Jacobians (``model``) and a Cauchy loss,
graduated from a wide scale to ``loss_scale_px`` (robust to 30-80 % outliers without a RANSAC
stage: the shared error is small, so identity is a good start). The bootstrap reuses per-frame
normal-equation blocks (one-step bootstrap: resampling frames with replacement = integer frame
weights, one Gauss-Newton step from the point estimate), so 100 rounds cost a few small solves.
Everything is float64 relative to the camera centroid, so georeferenced coordinates work.

Attribution (``selection``): world-only, calibration-only and joint fits. A significant shared
error that both single-block fits explain about equally well, or whose blocks are not separable,
is *ambiguous*: the registration estimate then reports the world-only fit (a misregistration is
still caught) and the calibration estimate the calibration-only fit, both flagged with the reason.
Drift (``drift``): windows grown to enough inliers, compared with the reference by paired
bootstrap, flagged on the lower bound, short runs rejected.

Coherence (``solver._coherence_p``): a registration's correction is a *shared* error only when
the frames pull together: a sign-flip test over frames (each frame's pull on the world block
flipped at random, the null of independent per-frame errors) gives its p-value; the verdict
stage fails a run on it only when significant.

Consensus (``screening``): before the fits pool the frames, each frame's own pose correction
(what the shared model leaves of its evidence) is tested against the null spread of all
frames' (Wald statistic, its scale estimated from the lower quartile, so it holds with up to
half the frames wrong); significant frames are left out, iteratively.

Modules: ``evidence`` (FrameEvidence + JSON), ``results`` (result types), ``settings`` (the
estimators' settings dataclasses), ``model``, ``solver``, ``selection``, ``effects``,
``registration``, ``calibration``, ``drift``, ``screening``.
"""

from __future__ import annotations

from pgt_check.geometry.shared_errors.calibration import estimate_calibration
from pgt_check.geometry.shared_errors.drift import estimate_drift
from pgt_check.geometry.shared_errors.evidence import REASONS, FrameEvidence
from pgt_check.geometry.shared_errors.registration import estimate_registration
from pgt_check.geometry.shared_errors.results import (
    CalibrationEstimate,
    DriftEstimate,
    DriftWindow,
    RegistrationEstimate,
)
from pgt_check.geometry.shared_errors.screening import FrameScreen, screen_frames
from pgt_check.geometry.shared_errors.settings import (
    CalibrationSettings,
    DriftSettings,
    FitSettings,
)
from pgt_check.geometry.shared_errors.solver import coherence_min_p

__all__ = [
    "REASONS",
    "CalibrationEstimate",
    "CalibrationSettings",
    "DriftEstimate",
    "DriftSettings",
    "DriftWindow",
    "FitSettings",
    "FrameEvidence",
    "FrameScreen",
    "RegistrationEstimate",
    "coherence_min_p",
    "estimate_calibration",
    "estimate_drift",
    "estimate_registration",
    "screen_frames",
]
