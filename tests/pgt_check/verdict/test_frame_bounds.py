"""Per-frame bounds (``pgt_check.verdict.frame_bounds``): which evidence points they rest on."""

from __future__ import annotations

import numpy as np
import pytest


def test_bound_rests_on_feature_points_when_they_suffice():
    """The geometric-edge points carry no parallax (their photo positions come from a 2D
    alignment model): the per-frame bound uses the raw points alone when they suffice."""
    from pgt_check.geometry.frame_accuracy import frame_accuracy
    from pgt_check.measure.record import AbsoluteEvidence
    from pgt_check.verdict.frame_bounds import FEATURE_ONLY_MIN_POINTS, bound_points

    rng = np.random.default_rng(0)
    k = np.array([[300.0, 0, 159.5], [0, 300.0, 119.5], [0, 0, 1]])
    n = 120
    pts = np.c_[rng.uniform(-1.5, 1.5, (n, 2)), rng.uniform(2.0, 6.0, n)]  # checked camera
    shift = np.array([0.15, 0.0, 0.0])  # the true camera is shifted: photo = K (p + t)

    def project(x: np.ndarray) -> np.ndarray:
        return (x @ k.T)[:, :2] / x[:, 2:3]

    raw2d = project(pts + shift) + rng.normal(0, 0.3, (n, 2))
    # edge points: the photo position from a 2D model of the motion (a shift of the image by
    # the mean displacement), no parallax
    mean_disp = (project(pts + shift) - project(pts)).mean(axis=0)
    edge2d = project(pts) + mean_disp
    both = AbsoluteEvidence(("raw", "edges"), tuple(map(tuple, np.r_[raw2d, edge2d])),
                            tuple(map(tuple, np.r_[pts, pts])), (n, n))
    p2, pc, src = bound_points(both)
    assert src == ("raw",) and len(p2) == n
    fa = frame_accuracy(p2, pc, k, 320, 240)
    assert fa.translation == pytest.approx(0.15, rel=0.1)
    pooled = frame_accuracy(np.r_[raw2d, edge2d], np.r_[pts, pts], k, 320, 240)
    assert pooled.translation < 0.9 * 0.15  # what the pooled points said: shift taken short
    few = AbsoluteEvidence(("raw", "edges"),
                           tuple(map(tuple, np.r_[raw2d[:10], edge2d])),
                           tuple(map(tuple, np.r_[pts[:10], pts])), (10, n))
    assert 10 < FEATURE_ONLY_MIN_POINTS and bound_points(few)[2] == ("raw", "edges")
