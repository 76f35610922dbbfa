"""The views a trusted calibration rests on, and which of another run's views they cover
(``verdict.calibration``; the allowance that uses them: test_shared.py)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from pgt_check.errors import InputError
from pgt_check.verdict.calibration import load_trusted_calibrations, uncovered_share, views_of


def _pose(x: float, yaw_deg: float) -> np.ndarray:
    a = np.radians(yaw_deg)
    m = np.eye(4)
    m[:3, :3] = [[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]]
    m[:3, 3] = [x, 0.0, 0.0]
    return m


def test_views_are_centres_and_optical_axes():
    v = views_of([_pose(1.0, 0.0), _pose(2.0, 90.0)])
    assert v.shape == (2, 6)
    np.testing.assert_allclose(v[0], [1, 0, 0, 0, 0, 1], atol=1e-12)
    np.testing.assert_allclose(v[1], [2, 0, 0, 1, 0, 0], atol=1e-12)
    assert views_of([]).shape == (0, 6)
    with pytest.raises(ValueError, match="world_from_cam"):
        views_of([np.eye(3)])


def test_a_segment_covers_its_own_views_not_the_rest_of_the_sweep():
    """A sweep of 40 views along x; a trusted run on its first quarter covers the views between
    its own, not the other three quarters; one spread along the sweep covers them all."""
    sweep = views_of([_pose(0.1 * i, 2.0 * i) for i in range(40)])
    # the trusted run's frames a little off the sweep's (no distance exactly at the radius)
    segment = views_of([_pose(0.1 * i + 0.013, 2.0 * i) for i in range(0, 10, 2)])
    spread = sweep[::4]
    assert uncovered_share(segment, sweep[1:9:2], depth=2.0) == 0.0
    assert uncovered_share(segment, sweep, depth=2.0) == pytest.approx(29 / 40)  # 0-10 covered
    assert uncovered_share(spread, sweep, depth=2.0) == 0.0
    # a moved copy of the trusted views (1 deg, 2 cm) is covered
    moved = views_of([_pose(0.1 * i + 0.02, 2.0 * i + 1.0) for i in range(0, 10, 2)])
    assert uncovered_share(segment, moved, depth=2.0) == 0.0
    # one trusted view covers only itself; none recorded: nothing is said to be uncovered
    assert uncovered_share(sweep[:1], sweep[:3], depth=2.0) == pytest.approx(2 / 3)
    assert uncovered_share(None, sweep, depth=2.0) == 0.0
    with pytest.raises(ValueError, match="depth"):
        uncovered_share(segment, sweep, depth=0.0)


def _summary(tmp_path, views):
    entry = {"rotation": np.eye(3).tolist(), "focal_scale": 1.0,
             "separable_from_registration": False, "views": views}
    path = tmp_path / "summary.json"
    path.write_text(json.dumps({"shared_errors": {"threshold_px": 2.4,
                                                  "calibration": {"cam0": entry}}}))
    return str(path)


def test_the_trusted_summary_carries_views_threshold_and_separability(tmp_path):
    (cal,) = load_trusted_calibrations(_summary(tmp_path, [[0, 0, 0, 0, 0, 1]])).values()
    assert cal.views is not None and cal.views.shape == (1, 6)
    assert cal.tolerance_px == 2.4 and not cal.separable
    (old,) = load_trusted_calibrations(_summary(tmp_path, None)).values()
    assert old.views is None


@pytest.mark.parametrize("views", [[[0, 0, 0]], [[0, 0, 0, 0, 0, float("nan")]], "x", [1, 2],
                                   [[1, 2, 3, 0, 0, 0]]])
def test_malformed_views_name_the_field(tmp_path, views):
    with pytest.raises(InputError, match=r"calibration\['cam0'\]\.views"):
        load_trusted_calibrations(_summary(tmp_path, views))
