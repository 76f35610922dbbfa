"""Attribution between registration and calibration (``geometry/shared_errors/selection.py``):
ambiguous when the blocks are not separable or explain the error about equally well."""

from __future__ import annotations

import numpy as np
import pytest

from pgt_check.geometry.shared_errors import (
    CalibrationSettings,
    FitSettings,
    estimate_calibration,
    estimate_registration,
)
from pgt_check.geometry.transforms import axis_angle_to_rotmat
from tests.pgt_check.geometry.shared_errors.synthetic import (
    THRESHOLD_PX,
    _within,
    make_evidence,
    similarity,
)


def test_same_viewing_direction_is_reported_as_ambiguous():
    rc = axis_angle_to_rotmat(np.array([1.0, 1.0, 0.3]), 0.8)
    ev = make_evidence(6, layout="line", cam_rotation=rc)
    reg = estimate_registration(ev)
    assert reg.success and reg.ambiguous_with_calibration and not reg.calibration_fitted
    assert reg.max_correlation > 0.995
    (cal,) = estimate_calibration(ev).values()
    assert cal.success and not cal.separable and not cal.registration_fitted


def test_equally_explained_error_is_ambiguous_even_when_separable_by_correlation():
    """Same viewing direction: world-only and calibration-only fits explain a camera rotation
    equally well. With the correlation test switched off, the cost test alone flags it; the
    registration reports the world-only fit (the error is still caught) and the calibration the
    calibration-only fit, both with the reason."""
    rc = axis_angle_to_rotmat(np.array([1.0, 1.0, 0.3]), 0.8)
    ev = make_evidence(6, layout="line", cam_rotation=rc)
    reg = estimate_registration(ev, FitSettings(max_correlation=1.01))
    assert reg.success and reg.ambiguous_with_calibration and not reg.calibration_fitted
    assert "about equally well" in reg.ambiguity and "not separable" not in reg.ambiguity
    assert abs(reg.gain_world_only - reg.gain_calibration_only) < 0.1 * reg.gain_world_only
    world_only = estimate_registration(ev, calibration="none")
    assert reg.effect_px == pytest.approx(world_only.effect_px, rel=1e-9)
    assert reg.exceeds(THRESHOLD_PX)
    (cal,) = estimate_calibration(ev, CalibrationSettings(max_correlation=1.01)).values()
    assert cal.success and not cal.separable and not cal.registration_fitted
    assert "about equally well" in cal.ambiguity
    assert _within(cal.equivalent_rotation_deg, 0.8, 0.1) and cal.exceeds(THRESHOLD_PX)


def test_misregistration_is_caught_when_ambiguous_and_clear_cases_are_not_ambiguous():
    c = similarity(2.0, (0.3, -0.5, 0.8), (0.08, -0.06, 0.05))
    # line layout: blocks not separable, but the world-only fit still measures the error
    line = estimate_registration(make_evidence(6, layout="line", world_error=lambda i: c))
    assert line.success and line.ambiguous_with_calibration and not line.calibration_fitted
    assert "not separable" in line.ambiguity
    assert _within(line.angle_deg, 2.0) and line.exceeds(THRESHOLD_PX)
    # loop: world error and intrinsics error are attributed without ambiguity
    loop = estimate_registration(make_evidence(1, world_error=lambda i: c))
    assert not loop.ambiguous_with_calibration and loop.ambiguity == ""
    assert loop.gain_world_only > 3 * loop.gain_calibration_only
    (cal,) = estimate_calibration(make_evidence(5, focal_scale=1.02, pp_shift=(5, 0))).values()
    assert cal.separable and cal.ambiguity == "" and cal.exceeds(THRESHOLD_PX)
    assert cal.gain_calibration_only > 3 * cal.gain_world_only
    # no significant shared error: nothing to attribute, not ambiguous even when inseparable
    clean = estimate_registration(make_evidence(6, layout="line"))
    assert clean.max_correlation > 0.995 and not clean.ambiguous_with_calibration
