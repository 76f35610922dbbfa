"""Property tests of the corner error and the homography guards (no rendering).

Expected outcomes: identity in -> 0 px out; a known homography in -> its analytic corner error;
degenerate match sets (collinear, one line, one cluster, duplicates, non-finite) and reflected /
singular / near-singular homographies -> a failure with a specific ``Reason``, never an
exception, never a NaN corner error on a success.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from pgt_check.geometry.homography import (
    HomographyConfig,
    Reason,
    check_homography,
    corner_error,
    corner_shift_and_zoom,
    estimate_homography,
    image_corners,
    scale_homography,
)

SETTINGS = settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
sizes = st.integers(min_value=1, max_value=8000)
shifts = st.floats(min_value=-500.0, max_value=500.0, allow_nan=False)


def _centre_scale(s: float, w: float, h: float) -> np.ndarray:
    """Scaling by s about the centre of the outer pixel box of a w x h image."""
    cx, cy = (w - 1) / 2, (h - 1) / 2
    return np.array([[s, 0, cx * (1 - s)], [0, s, cy * (1 - s)], [0, 0, 1.0]])


@SETTINGS
@given(w=sizes, h=sizes)
def test_identity_gives_zero_and_passes_the_guards(w, h):
    """Identity -> corner error exactly 0, shift 0, zoom 1, no guard fires."""
    assert corner_error(np.eye(3), w, h) == 0.0
    assert corner_shift_and_zoom(np.eye(3), w, h) == (0.0, 0.0, 1.0)
    assert check_homography(np.eye(3), w, h) is None


@SETTINGS
@given(w=sizes, h=sizes, dx=shifts, dy=shifts, k=st.floats(0.01, 100.0))
def test_translation_gives_its_length(w, h, dx, dy, k):
    """A pure translation moves every corner by (dx, dy); the overall scale of H is irrelevant."""
    t = np.array([[1, 0, dx], [0, 1, dy], [0, 0, 1.0]])
    assert corner_error(t * k, w, h) == pytest.approx(math.hypot(dx, dy), abs=1e-6)
    sdx, sdy, zoom = corner_shift_and_zoom(t, w, h)
    assert (sdx, sdy) == (pytest.approx(dx, abs=1e-6), pytest.approx(dy, abs=1e-6))
    assert zoom == pytest.approx(1.0)


@SETTINGS
@given(w=st.integers(2, 8000), h=st.integers(2, 8000), s=st.floats(0.3, 3.0))
def test_centre_scale_gives_half_diagonal_times_change(w, h, s):
    """Zoom s about the centre: each corner moves by |s - 1| * half the outer diagonal."""
    expected = abs(s - 1) * math.hypot(w, h) / 2
    assert corner_error(_centre_scale(s, w, h), w, h) == pytest.approx(expected, rel=1e-9, abs=1e-9)


@SETTINGS
@given(
    w=st.integers(8, 4000),
    h=st.integers(8, 4000),
    dx=shifts,
    dy=shifts,
    sx=st.floats(0.05, 1.0),
    sy=st.floats(0.05, 1.0),
)
def test_scale_homography_preserves_translation_and_identity(w, h, dx, dy, sx, sy):
    """A working-size translation (dx, dy) is (dx/sx, dy/sy) in original pixels; I stays I."""
    np.testing.assert_allclose(scale_homography(np.eye(3), sx, sy), np.eye(3), atol=1e-12)
    t = np.array([[1, 0, dx], [0, 1, dy], [0, 0, 1.0]])
    err = corner_error(scale_homography(t, sx, sy), w, h)
    assert err == pytest.approx(math.hypot(dx / sx, dy / sy), rel=1e-9, abs=1e-6)


@SETTINGS
@given(
    h=arrays(np.float64, (3, 3), elements=st.floats(width=64) | st.floats(-2.0, 2.0)),
    w=st.integers(1, 5000),
    ht=st.integers(1, 5000),
)
def test_guards_never_raise_and_pass_only_finite(h, w, ht):
    """Arbitrary 3x3 input: the guard answers (no exception); whatever it accepts has finite
    corner error."""
    reason = check_homography(h, w, ht)
    if reason is None:
        assert math.isfinite(corner_error(h, w, ht))
    else:
        assert isinstance(reason, Reason)


@pytest.mark.parametrize(
    "h, reason",
    [
        (
            np.diag([-1.0, 1.0, 1.0]) @ np.array([[1, 0, -639.0], [0, 1, 0], [0, 0, 1]]),
            Reason.ORIENTATION_FLIP,
        ),  # mirrored left-right onto the same image box
        (np.array([[1, 0, 0], [0, -1, 479.0], [0, 0, 1]]), Reason.ORIENTATION_FLIP),
        (np.array([[1, 0, 0], [0, 1, 0], [0, 0, 0.0]]), Reason.ILL_CONDITIONED),  # singular
        (np.array([[1, 1, 0], [1, 1 + 1e-12, 0], [0, 0, 1.0]]), Reason.ILL_CONDITIONED),
        (np.array([[1, 0, 0], [0, 1, 0], [-0.004, 0, 1.0]]), Reason.ILL_CONDITIONED),  # horizon
        (np.array([[1, 0, 0], [0, 1, 0], [0, 0, np.nan]]), Reason.NON_FINITE),
        (np.diag([10.0, 10.0, 1.0]), Reason.ILL_CONDITIONED),  # area x100
        (np.zeros((3, 3)), Reason.ILL_CONDITIONED),
    ],
    ids=[
        "mirror-x",
        "mirror-y",
        "singular",
        "near-singular",
        "through-infinity",
        "nan",
        "huge-zoom",
        "zero",
    ],
)
def test_bad_homographies_are_rejected(h, reason):
    """Reflected, singular, near-singular, horizon-crossing, non-finite -> the stated reason."""
    assert check_homography(h, 640, 480) == reason


def _grid(n: int = 64, w: float = 320, h: float = 240, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return rng.uniform([5, 5], [w - 5, h - 5], size=(n, 2))


def _apply(h: np.ndarray, p: np.ndarray) -> np.ndarray:
    q = np.c_[p, np.ones(len(p))] @ h.T
    return q[:, :2] / q[:, 2:]


@SETTINGS
@given(
    dx=st.floats(-20, 20),
    dy=st.floats(-20, 20),
    s=st.floats(0.8, 1.25),
    a=st.floats(-0.1, 0.1),
    seed=st.integers(0, 1000),
)
def test_known_homography_in_gives_its_corner_error(dx, dy, s, a, seed):
    """Exact matches under a known near-identity H: the estimate's corner error is H's."""
    c, si = math.cos(a), math.sin(a)
    h = np.array([[s * c, -s * si, dx], [s * si, s * c, dy], [0, 0, 1.0]])
    assume(check_homography(h, 320, 240) is None)
    src = _grid(seed=seed)
    res = estimate_homography(src, _apply(h, src), 320, 240)
    assert res.success, res.reason
    assert corner_error(res.photo_from_render, 320, 240) == pytest.approx(
        corner_error(h, 320, 240), abs=0.05
    )


def test_identity_matches_give_zero_error():
    src = _grid()
    res = estimate_homography(src, src.copy(), 320, 240)
    assert res.success and corner_error(res.photo_from_render, 320, 240) < 1e-3


def _line(n=60, noise=0.0, seed=0):
    rng = np.random.default_rng(seed)
    t = rng.uniform(0, 1, n)
    p = np.c_[20 + 280 * t, 30 + 150 * t]
    return p + rng.normal(0, noise, p.shape)


@pytest.mark.parametrize(
    "render, photo, reason",
    [
        (_line(), _line() + 3, Reason.DEGENERATE_MATCHES),  # exactly collinear
        (_line(noise=0.05), _line(noise=0.05) + 3, Reason.DEGENERATE_MATCHES),  # nearly
        (
            np.tile([[100.0, 80.0]], (40, 1)),
            np.tile([[102.0, 81.0]], (40, 1)),
            Reason.DEGENERATE_MATCHES,
        ),  # one point duplicated
        (
            np.repeat(_grid(3), 15, axis=0),
            np.repeat(_grid(3), 15, axis=0),
            Reason.DEGENERATE_MATCHES,
        ),  # three distinct points, duplicated
        (
            100 + np.random.default_rng(1).normal(0, 0.2, (50, 2)),
            102 + np.random.default_rng(2).normal(0, 0.2, (50, 2)),
            Reason.DEGENERATE_MATCHES,
        ),  # one tight cluster
        (_grid(8), _grid(8), Reason.TOO_FEW_MATCHES),
        (np.full((40, 2), np.nan), np.full((40, 2), np.nan), Reason.TOO_FEW_MATCHES),
        (np.zeros((0, 2)), np.zeros((0, 2)), Reason.TOO_FEW_MATCHES),
        (_grid(), _grid(seed=99), None),  # random: no consistent H (any failure reason)
        (_grid(), np.c_[319 - _grid()[:, 0], _grid()[:, 1]], Reason.ORIENTATION_FLIP),  # mirror
    ],
    ids=[
        "collinear",
        "near-collinear",
        "one-point",
        "three-points",
        "cluster",
        "too-few",
        "all-nan",
        "empty",
        "random",
        "mirrored",
    ],
)
def test_degenerate_match_sets_fail_with_a_reason(render, photo, reason):
    """Degenerate or inconsistent matches -> success False with a specific reason."""
    res = estimate_homography(render, photo, 320, 240)
    assert not res.success and res.photo_from_render is None
    assert isinstance(res.reason, Reason)
    if reason is Reason.ORIENTATION_FLIP:  # OpenCV's USAC may already refuse a mirrored fit
        assert res.reason in (Reason.ORIENTATION_FLIP, Reason.ESTIMATION_FAILED)
    elif reason is not None:
        assert res.reason == reason
    assert len(res.inliers) == len(render)


@SETTINGS
@given(
    pts=arrays(
        np.float64,
        st.tuples(st.integers(0, 40), st.just(4)),
        elements=st.floats(-1e4, 1e4) | st.sampled_from([np.nan, np.inf, 1e300]),
    ),
)
def test_estimate_never_raises(pts):
    """Any (N, 2) pair of point sets, including NaN/inf/huge values -> a result, no exception;
    a success is a guarded, finite homography."""
    res = estimate_homography(pts[:, :2], pts[:, 2:], 320, 240)
    if res.success:
        assert check_homography(res.photo_from_render, 320, 240) is None
        assert math.isfinite(corner_error(res.photo_from_render, 320, 240))
    else:
        assert isinstance(res.reason, Reason)


def test_guard_config_is_size_independent():
    """The condition guard works in normalised coordinates: a 32 px and a 6000 px image treat
    the same relative warp alike."""
    for w, h in [(32, 24), (6000, 4000)]:
        assert check_homography(_centre_scale(1.1, w, h), w, h) is None
        assert (
            check_homography(_centre_scale(5.0, w, h), w, h, HomographyConfig(max_area_ratio=16))
            == Reason.ILL_CONDITIONED
        )
    assert image_corners(1, 1).tolist() == [[-0.5, -0.5], [0.5, -0.5], [0.5, 0.5], [-0.5, 0.5]]
