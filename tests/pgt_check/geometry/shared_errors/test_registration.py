"""``estimate_registration`` (``geometry/shared_errors/registration.py``) on synthetic loops
(``synthetic.py``): identity, rigid and similarity errors, georeferenced offsets, degenerate
input."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from pgt_check.geometry.shared_errors import (
    FitSettings,
    coherence_min_p,
    estimate_calibration,
    estimate_drift,
    estimate_registration,
)
from tests.pgt_check.geometry.shared_errors.synthetic import (
    THRESHOLD_PX,
    _within,
    make_evidence,
    similarity,
)


def test_correct_trajectory_gives_identity():
    ev = make_evidence(0)
    reg = estimate_registration(ev)
    assert reg.success, reg.reason
    assert not reg.calibration_fitted and not reg.ambiguous_with_calibration  # not needed
    assert reg.angle_deg < 0.1 and reg.translation < 0.01
    assert reg.effect_px_ci[1] < 1.0
    assert not reg.exceeds(THRESHOLD_PX)
    assert reg.n_frames == 40 and reg.n_points == 4000
    assert 0.6 < reg.n_inliers / reg.n_points < 0.8  # 30 % outliers rejected
    assert reg.residual_median_after < 1.5
    assert 2.5 < reg.median_scene_depth < 3.5
    (cal,) = estimate_calibration(ev).values()
    assert cal.success and not cal.exceeds(THRESHOLD_PX)
    assert cal.equivalent_rotation_deg < 0.05 and abs(cal.focal_scale - 1) < 1e-3


@pytest.mark.parametrize(
    "seed,angle,axis,t",
    [(1, 2.0, (0.3, -0.5, 0.8), (0.08, -0.06, 0.05)), (2, 1.0, (1, 0.2, 0.1), (0, 0.05, -0.03))],
)
def test_rigid_misregistration_is_recovered(seed, angle, axis, t):
    c = similarity(angle, axis, t)  # true = c @ checked
    ev = make_evidence(seed, world_error=lambda i: c)
    reg = estimate_registration(ev)
    assert reg.success, reg.reason
    assert _within(reg.angle_deg, angle) and _within(reg.translation, np.linalg.norm(t))
    assert reg.exceeds(THRESHOLD_PX)
    assert reg.angle_deg_ci[0] < angle < reg.angle_deg_ci[1] + 0.05
    assert reg.residual_median_after < 1.5 < reg.residual_median_before
    # the corrected poses are the true ones
    true = c @ ev[5].world_from_cam
    corrected = reg.correct(ev[5].world_from_cam)
    np.testing.assert_allclose(corrected[:3, 3], true[:3, 3], atol=0.01)
    np.testing.assert_allclose(corrected[:3, :3], true[:3, :3], atol=2e-3)
    # calibration is not blamed for a world error (the world block is needed and fitted)
    (cal,) = estimate_calibration(ev).values()
    assert cal.registration_fitted and not cal.exceeds(THRESHOLD_PX)


def test_similarity_scale_is_recovered():
    c = similarity(0.5, (0, 0, 1), (0.02, 0, 0), scale=1.03)
    ev = make_evidence(3, world_error=lambda i: c)
    reg = estimate_registration(ev, similarity=True)
    assert reg.success, reg.reason
    assert abs(reg.scale - 1.03) < 0.3 * 0.03
    assert reg.scale_ci[0] < 1.03 < reg.scale_ci[1] + 1e-3
    assert reg.exceeds(THRESHOLD_PX)
    rigid = estimate_registration(ev)
    assert rigid.scale == 1.0 and rigid.residual_median_after > reg.residual_median_after


def test_georeferenced_offset_gives_the_same_answer():
    c = similarity(2.0, (0.3, -0.5, 0.8), (0.08, -0.06, 0.05))
    local = estimate_registration(make_evidence(1, world_error=lambda i: c))
    geo = estimate_registration(
        make_evidence(1, world_error=lambda i: c, offset=(1e6, -2e6, 300.0))
    )
    assert geo.success
    assert abs(geo.angle_deg - local.angle_deg) < 1e-4
    assert abs(geo.translation - local.translation) < 1e-5
    assert abs(geo.effect_px - local.effect_px) < 1e-3
    np.testing.assert_allclose(
        geo.corrected_world_from_world[:3, :3], local.corrected_world_from_world[:3, :3], atol=1e-8
    )


def test_degenerate_input_fails_with_a_reason():
    ev = make_evidence(0, n_frames=6)
    assert estimate_registration([]).reason == "too_few_frames"
    assert estimate_registration(ev[:1]).reason == "too_few_frames"
    empty = [replace(e, pts2d=np.zeros((0, 2)), pts3d=np.zeros((0, 3))) for e in ev]
    assert estimate_registration(empty).reason == "too_few_points"
    nan = [replace(e, pts2d=np.full_like(e.pts2d, np.nan)) for e in ev]
    assert estimate_registration(nan).reason == "too_few_points"
    junk = make_evidence(0, n_frames=10, outliers=1.0)
    reg = estimate_registration(junk)
    assert not reg.success and reg.reason in ("too_few_inliers", "ill_conditioned")
    assert not reg.exceeds(THRESHOLD_PX)
    assert not estimate_drift(ev[:1]).success
    (cal,) = estimate_calibration(empty).values()
    assert not cal.success and cal.reason == "too_few_points"


def _own_errors(seed: int, deg: float, t: float):
    """Per-frame errors of their own: each frame rotated by ``deg`` about a random axis and
    moved by ``t`` in a random direction (true = C_i @ checked)."""
    rng = np.random.default_rng(1000 + seed)
    table = [similarity(deg, rng.normal(size=3), t * rng.normal(size=3) / np.sqrt(3))
             for _ in range(64)]
    return lambda i: table[i]


def test_coherence_tells_a_shared_error_from_frames_own_errors():
    """The sign-flip test (``RegistrationEstimate.coherence_p``): a world error shared by every
    frame is significant beside per-frame errors of a third of its size; per-frame errors of
    their own alone are not, at about the test's level, though the fit makes a correction of
    them (12 frames: the exact enumeration; 30: random patterns)."""
    shared = similarity(1.5, (0.3, -0.5, 0.8), (0.05, -0.03, 0.02))
    sig_shared, sig_own, big_own = 0, 0, 0
    for seed in range(10):
        own = _own_errors(seed, 0.5, 0.015)
        n = 12 if seed % 2 else 30
        ev = make_evidence(seed, n_frames=n, world_error=lambda i, own=own: shared @ own(i))
        reg = estimate_registration(ev)
        assert reg.success and 0.0 < reg.coherence_p <= 1.0
        sig_shared += reg.coherence_p <= 0.05
        ev = make_evidence(seed, n_frames=n, world_error=_own_errors(seed, 2.0, 0.06))
        reg = estimate_registration(ev)
        assert reg.success
        sig_own += reg.coherence_p <= 0.05
        big_own += reg.exceeds(THRESHOLD_PX)
    assert sig_shared == 10
    assert sig_own <= 2, sig_own  # the null's 5 % of 10 runs
    assert big_own >= 3, big_own  # the fitted correction alone would have failed these runs


def test_coherence_can_be_switched_off_and_its_resolution():
    ev = make_evidence(0, n_frames=12)
    assert np.isnan(estimate_registration(ev, FitSettings(coherence=False)).coherence_p)
    assert np.isfinite(estimate_registration(ev).coherence_p)
    assert coherence_min_p(5) > 0.05 >= coherence_min_p(6)  # 2 / 2^F: 6 frames can reject
    assert coherence_min_p(40) < 1e-3
