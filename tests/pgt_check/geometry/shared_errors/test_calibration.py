"""``estimate_calibration`` (``geometry/shared_errors/calibration.py``): intrinsics errors, a
camera-frame rotation and a camera-to-rig translation are calibration, not registration."""

from __future__ import annotations

import numpy as np

from pgt_check.geometry.shared_errors import (
    CalibrationSettings,
    estimate_calibration,
    estimate_registration,
)
from pgt_check.geometry.transforms import axis_angle_to_rotmat
from tests.pgt_check.geometry.shared_errors.synthetic import (
    THRESHOLD_PX,
    _within,
    make_evidence,
)


def test_intrinsics_error_is_calibration_not_registration():
    ev = make_evidence(5, focal_scale=1.02, pp_shift=(5.0, 0.0))
    (cal,) = estimate_calibration(ev).values()
    assert cal.success and cal.separable and not cal.registration_fitted  # not needed
    assert _within(cal.focal_scale - 1, 0.02)
    assert (
        _within(cal.principal_point_shift_px[0], 5.0) and abs(cal.principal_point_shift_px[1]) < 1
    )
    assert cal.exceeds(THRESHOLD_PX)
    reg = estimate_registration(ev)
    assert reg.success and not reg.exceeds(THRESHOLD_PX)


def test_camera_frame_rotation_is_calibration_not_registration():
    rc = axis_angle_to_rotmat(np.array([1.0, 1.0, 0.3]), 0.8)
    ev = make_evidence(4, cam_rotation=rc)
    (cal,) = estimate_calibration(ev).values()
    assert cal.success and cal.separable
    assert _within(cal.equivalent_rotation_deg, 0.8, 0.1)
    np.testing.assert_allclose(cal.rotation, rc, atol=5e-4)
    assert cal.exceeds(THRESHOLD_PX)
    reg = estimate_registration(ev)
    assert reg.success and reg.calibration_fitted and not reg.exceeds(THRESHOLD_PX)
    # without the calibration nuisance the same data looks like a registration error
    assert estimate_registration(ev, calibration="none").exceeds(THRESHOLD_PX)


def test_camera_to_rig_translation_is_estimated_and_removed():
    """Photos from a camera 5 cm beside the posed sensor (scene depths 2-4 m): with
    ``calibration_translation`` the calibration estimate recovers the offset, and removing it
    leaves evidence consistent with the trajectory; without it only a rotation is fitted and
    a depth-dependent residual remains."""
    from pgt_check.verdict.calibration import CameraCalibration

    t = np.array([0.05, 0.0, 0.0])
    ev = make_evidence(4, noise_px=0.5, outliers=0.1, cam_translation=t)
    with_translation = CalibrationSettings(calibration_translation=True)
    (cal,) = estimate_calibration(ev, with_translation, registration="none").values()
    assert cal.success and cal.translation_fitted
    np.testing.assert_allclose(cal.translation, t, atol=0.3 * 0.05)
    assert np.all(cal.translation_ci[:, 0] - 1e-3 <= t) and np.all(
        t <= cal.translation_ci[:, 1] + 1e-3
    )
    (rot_only,) = estimate_calibration(ev, registration="none").values()
    assert not rot_only.translation_fitted and not np.any(rot_only.translation)
    removed = [CameraCalibration.from_estimate(cal).remove(e) for e in ev]
    after = estimate_registration(removed, calibration="none")
    assert after.success and not after.exceeds(THRESHOLD_PX)
    assert after.residual_median_after < 1.0
    # the rotation-only model leaves more behind
    kept = [CameraCalibration.from_estimate(rot_only).remove(e) for e in ev]
    assert estimate_registration(kept, calibration="none").residual_median_after > (
        after.residual_median_after
    )
