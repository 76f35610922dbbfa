"""The observation model's analytic Jacobian against central finite differences, for every
block layout (world, similarity, calibration with and without translation, several cameras)."""

from __future__ import annotations

import numpy as np
import pytest

from pgt_check.geometry.shared_errors.model import (
    _layout,
    _Problem,
    _residuals,
    _rodrigues,
    _State,
    _update,
)


def _problem(n_frames: int, n_cams: int, n_cal: int, seed: int) -> _Problem:
    rng = np.random.default_rng(seed)
    per = 15
    n = n_frames * per
    rt = _rodrigues(rng.normal(0, 0.4, (n_frames, 3)))
    centre = rng.normal(0, 0.5, (n_frames, 3))
    fidx = np.repeat(np.arange(n_frames), per)
    in_cam = np.c_[rng.uniform(-1, 1, (n, 2)), rng.uniform(1.0, 4.0, n)]
    y = np.einsum("nji,nj->ni", rt[fidx], in_cam) + centre[fidx]
    k = np.array([[500.0, 0.4, 320.0], [0.0, 510.0, 240.0], [0.0, 0.0, 1.0]])
    return _Problem(
        origin=np.zeros(3), frame_ids=tuple(str(i) for i in range(n_frames)),
        index=np.arange(n_frames), cam=np.arange(n_frames) % n_cams,
        camera_ids=tuple(f"c{i}" for i in range(n_cams)), rt=rt, centre=centre,
        K=np.tile(k, (n_frames, 1, 1)), y=y, obs=rng.uniform(0, 640, (n, 2)), fidx=fidx,
        starts=np.arange(n_frames) * per, n_cal=n_cal,
    )  # fmt: skip


def _state(n_cams: int, seed: int) -> _State:
    rng = np.random.default_rng(seed + 100)
    return _State(
        _rodrigues(rng.normal(0, 0.02, 3)), rng.normal(0, 0.02, 3), 0.01,
        _rodrigues(rng.normal(0, 0.02, (n_cams, 3))), rng.normal(0, 0.01, n_cams),
        rng.normal(0, 0.02, (n_cams, 3)),
    )  # fmt: skip


@pytest.mark.parametrize("n_cams,n_cal", [(1, 4), (1, 7), (3, 4), (2, 7)])
@pytest.mark.parametrize("world,similarity,calib", [(True, False, False), (True, True, False),
                                                    (False, False, True), (True, True, True)])
def test_jacobian_matches_finite_differences(n_cams, n_cal, world, similarity, calib):
    p = _problem(6, n_cams, n_cal, seed=n_cams * 10 + n_cal)
    st = _state(n_cams, seed=n_cal)
    kw = dict(world=world, similarity=similarity, calib=calib)
    r0, jm = _residuals(p, st, jac=True, **kw)
    r_plain, none = _residuals(p, st)
    assert none is None and np.array_equal(r0, r_plain)
    ncol = _layout(p, world, similarity, calib)[2]
    assert jm.shape == (len(r0), 2, ncol)
    h = 1e-6
    for c in range(ncol):
        step = np.zeros(ncol)
        step[c] = h
        rp, _ = _residuals(p, _update(p, st, step, **kw))
        rm, _ = _residuals(p, _update(p, st, -step, **kw))
        numeric = (rp - rm) / (2 * h)
        np.testing.assert_allclose(jm[:, :, c], numeric, rtol=1e-5, atol=1e-4 * (1 + np.abs(
            numeric).max()), err_msg=f"column {c}")
