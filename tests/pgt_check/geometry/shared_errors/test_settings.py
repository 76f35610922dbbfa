"""The estimators' settings (``geometry/shared_errors/settings.py``): the documented defaults,
each estimator's own differences, and that the estimators read them."""

from __future__ import annotations

import dataclasses
import math

import pytest

from pgt_check.geometry.shared_errors import (
    CalibrationSettings,
    DriftSettings,
    FitSettings,
    estimate_calibration,
    estimate_drift,
    estimate_registration,
)
from tests.pgt_check.geometry.shared_errors.synthetic import make_evidence, similarity

SHARED_DEFAULTS = dict(
    n_bootstrap=100,
    seed=0,
    loss_scale_px=2.0,
    max_error_px=6.0,
    min_points_per_frame=6,
    max_correlation=0.985,
    model_penalty=2.0,
    ambiguity_margin=0.1,
    coherence=True,
    calibration_translation=False,
)


def _values(settings) -> dict:
    return {f.name: getattr(settings, f.name) for f in dataclasses.fields(settings)}


def test_defaults_are_the_documented_ones():
    assert _values(FitSettings()) == {**SHARED_DEFAULTS, "min_frames": 5, "min_inliers": 30}
    # calibration needs fewer frames; everything else as registration
    assert _values(CalibrationSettings()) == {
        **SHARED_DEFAULTS, "min_frames": 3, "min_inliers": 30,
    }  # fmt: skip
    # drift: min_inliers is what the reference (global) estimate needs
    assert _values(DriftSettings()) == {
        **SHARED_DEFAULTS, "min_frames": 5, "min_inliers": 12, "window": 0.2, "step": 0.5,
        "min_window_inliers": 150, "min_points": 60, "min_segment_windows": 2,
        "min_segment_frames": 3,
    }  # fmt: skip
    assert isinstance(CalibrationSettings(), FitSettings)
    assert isinstance(DriftSettings(), FitSettings)


def test_settings_are_frozen():
    with pytest.raises(dataclasses.FrozenInstanceError):
        FitSettings().n_bootstrap = 0  # type: ignore[misc]


def test_without_bootstrap_there_is_no_interval():
    c = similarity(2.0, (0.3, -0.5, 0.8), (0.08, -0.06, 0.05))
    ev = make_evidence(1, n_frames=12, world_error=lambda i: c)
    full = estimate_registration(ev)
    assert full.success and all(math.isfinite(x) for x in full.effect_px_ci)
    assert estimate_registration(ev, FitSettings()).effect_px == full.effect_px  # None: defaults
    bare = estimate_registration(ev, FitSettings(n_bootstrap=0))
    assert bare.success and all(math.isnan(x) for x in bare.effect_px_ci)
    # the point estimate does not depend on it (up to rounding: batched with the resamples)
    assert bare.effect_px == pytest.approx(full.effect_px, rel=1e-12)
    (cal,) = estimate_calibration(ev, CalibrationSettings(n_bootstrap=0)).values()
    assert cal.success and all(math.isnan(x) for x in cal.effect_px_ci)


def test_each_estimator_keeps_its_own_min_frames():
    ev = make_evidence(2, n_frames=4)
    assert estimate_registration(ev).reason == "too_few_frames"  # 5 needed
    (cal,) = estimate_calibration(ev).values()  # 3 needed
    assert cal.reason != "too_few_frames"
    assert estimate_registration(ev, FitSettings(min_frames=3)).reason != "too_few_frames"
    # drift needs twice min_frames over the run
    assert estimate_drift(make_evidence(2, n_frames=9)).reason == "too_few_frames"
