import numpy as np
import pytest

from pgt_check.geometry.homography import (
    HomographyConfig,
    Reason,
    apply_homography,
    auc_at_thresholds,
    check_homography,
    corner_error,
    corner_shift_and_zoom,
    estimate_homography,
    image_corners,
    scale_homography,
)

W, H = 640, 480


def _grid_points(n=200, seed=0):
    rng = np.random.default_rng(seed)
    return rng.uniform([0, 0], [W - 1, H - 1], size=(n, 2))


def test_identity_has_zero_corner_error():
    assert corner_error(np.eye(3), W, H) == 0.0


def test_translation_corner_error_equals_shift():
    h = np.eye(3)
    h[:2, 2] = [3.0, 4.0]
    assert corner_error(h, W, H) == pytest.approx(5.0)
    dx, dy, zoom = corner_shift_and_zoom(h, W, H)
    assert (dx, dy, zoom) == pytest.approx((3.0, 4.0, 1.0))


def test_zoom_about_centre():
    c = np.array([(W - 1) / 2, (H - 1) / 2])
    s = 1.1
    h = np.array([[s, 0, c[0] * (1 - s)], [0, s, c[1] * (1 - s)], [0, 0, 1]])
    dx, dy, zoom = corner_shift_and_zoom(h, W, H)
    assert zoom == pytest.approx(1.1)
    assert abs(dx) < 1e-9 and abs(dy) < 1e-9
    half_diag = np.hypot(W, H) / 2
    assert corner_error(h, W, H) == pytest.approx(0.1 * half_diag)


def test_corners_follow_opencv_pixel_convention():
    c = image_corners(4, 2)
    np.testing.assert_allclose(c, [[-0.5, -0.5], [3.5, -0.5], [3.5, 1.5], [-0.5, 1.5]])


def test_estimate_recovers_known_homography():
    rng = np.random.default_rng(1)
    h_true = np.array([[1.01, 0.01, 4.0], [-0.008, 0.995, -3.0], [1e-5, -2e-5, 1.0]])
    p0 = _grid_points(300)
    p1 = apply_homography(h_true, p0) + rng.normal(0, 0.3, size=p0.shape)
    # 30 % outliers
    out = rng.choice(len(p0), 90, replace=False)
    p1[out] = rng.uniform([0, 0], [W, H], size=(90, 2))
    res = estimate_homography(p0, p1, W, H)
    assert res.success and res.reason is None
    assert res.n_inliers >= 180
    assert not res.inliers[out].mean() > 0.1
    err_true = corner_error(h_true, W, H)
    assert corner_error(res.photo_from_render, W, H) == pytest.approx(err_true, abs=1.0)


def test_too_few_matches():
    p = _grid_points(5)
    res = estimate_homography(p, p, W, H)
    assert not res.success and res.reason == Reason.TOO_FEW_MATCHES
    assert res.photo_from_render is None and res.inliers.shape == (5,)


def test_collinear_points_are_degenerate():
    x = np.linspace(0, W, 50)
    p = np.stack([x, 0.5 * x], axis=1)
    res = estimate_homography(p, p + 1.0, W, H)
    assert not res.success and res.reason == Reason.DEGENERATE_MATCHES


def test_single_cluster_is_degenerate():
    rng = np.random.default_rng(2)
    p = np.array([100.0, 100.0]) + rng.normal(0, 0.05, size=(60, 2))
    res = estimate_homography(p, p, W, H)
    assert not res.success and res.reason == Reason.DEGENERATE_MATCHES


def test_non_finite_points_are_ignored():
    p = _grid_points(100)
    q = p.copy()
    q[:5] = np.nan
    res = estimate_homography(p, q, W, H)
    assert res.success
    assert not res.inliers[:5].any()
    assert corner_error(res.photo_from_render, W, H) < 0.5


def test_mirrored_matches_are_rejected_as_flip():
    p0 = _grid_points(100)
    p1 = p0.copy()
    p1[:, 0] = (W - 1) - p1[:, 0]
    res = estimate_homography(p0, p1, W, H)
    # USAC's own orientation test may refuse the model before our guard sees it
    assert not res.success
    assert res.reason in (Reason.ORIENTATION_FLIP, Reason.ESTIMATION_FAILED)


@pytest.mark.parametrize(
    "h,reason",
    [
        (np.full((3, 3), np.nan), Reason.NON_FINITE),
        (np.diag([-1.0, 1.0, 1.0]), Reason.ORIENTATION_FLIP),
        (np.array([[1, 0, 0], [0, 1, 0], [-0.01, 0, 1.0]]), Reason.ILL_CONDITIONED),  # line at inf crosses
        (np.diag([1e-5, 1e-5, 1.0]), Reason.ILL_CONDITIONED),
        (np.diag([10.0, 10.0, 1.0]), Reason.ILL_CONDITIONED),  # area x100
    ],
)
def test_check_homography_guards(h, reason):
    assert check_homography(h, W, H) == reason


def test_check_homography_accepts_small_perturbation():
    h = np.array([[1.02, 0.01, 5], [0.0, 0.98, -4], [1e-5, 0, 1]])
    assert check_homography(h, W, H) is None


def test_scale_homography_maps_original_pixels():
    # working images at half size: x_w = (x + .5) * .5 - .5
    h_orig = np.eye(3)
    h_orig[:2, 2] = [8.0, -6.0]
    s = 0.5
    S = np.array([[s, 0, 0.5 * s - 0.5], [0, s, 0.5 * s - 0.5], [0, 0, 1]])
    h_work = S @ h_orig @ np.linalg.inv(S)
    np.testing.assert_allclose(scale_homography(h_work, s, s), h_orig, atol=1e-12)
    assert corner_error(h_work, W * s, H * s) == pytest.approx(5.0)
    assert corner_error(scale_homography(h_work, s, s), W, H) == pytest.approx(10.0)


def test_auc_counts_failures_in_denominator():
    a = auc_at_thresholds(np.array([0.0, 0.0]), (1.0,))
    b = auc_at_thresholds(np.array([0.0, 0.0, np.inf, np.inf]), (1.0,))
    assert a["auc@1px"] == pytest.approx(1.0)
    assert b["auc@1px"] == pytest.approx(0.5)
    assert auc_at_thresholds(np.array([]), (1.0,))["auc@1px"] == 0.0
    # recall is interpolated linearly from (0, 0) (glue-factory's definition)
    c = auc_at_thresholds(np.array([0.5]), (1.0,))
    assert c["auc@1px"] == pytest.approx(0.75)


def test_config_min_inliers_enforced():
    p0 = _grid_points(30)
    res = estimate_homography(p0, p0, W, H, HomographyConfig(min_matches=4, min_inliers=40))
    assert not res.success and res.reason == Reason.TOO_FEW_INLIERS


def test_auc_matches_the_trapezoid_rule_on_random_errors():
    """The written-out trapezoid rule (NumPy 1.24 has no np.trapezoid) against a dense integral
    of the recall curve: linear between the sorted errors (0 at 0), flat after the last one."""
    rng = np.random.default_rng(3)
    errors = np.concatenate([rng.uniform(0, 6, 50), [np.inf] * 5])
    got = auc_at_thresholds(errors, (1.0, 3.0, 5.0))
    e = np.concatenate([[0.0], np.sort(errors)])
    r = np.arange(len(e)) / len(errors)
    for t in (1.0, 3.0, 5.0):
        xs = np.linspace(0, t, 200_001)
        inside = e < t
        curve = np.interp(xs, e[inside], r[inside])
        assert got[f"auc@{t:g}px"] == pytest.approx(curve.mean(), abs=1e-4)
        assert 0.0 < got[f"auc@{t:g}px"] < 1.0
