import numpy as np
import pytest

from pgt_check.geometry.transforms import pose_difference
from pgt_check.types import Camera, Frame, Trajectory
from pgt_eval import perturb_pose, perturb_trajectory, roc_auc


def test_roc_auc_basic():
    assert roc_auc([1, 2, 3, 4], [0, 0, 1, 1]) == 1.0
    assert roc_auc([4, 3, 2, 1], [0, 0, 1, 1]) == 0.0
    assert roc_auc([1, 1, 1, 1], [0, 1, 0, 1]) == 0.5
    # unverifiable (inf) positives count as detected
    assert roc_auc([1, 2, np.inf], [0, 0, 1]) == 1.0
    with pytest.raises(ValueError):
        roc_auc([1, 2], [1, 1])


def test_perturb_pose_has_requested_magnitudes():
    rng = np.random.default_rng(0)
    p = np.eye(4)
    q = perturb_pose(p, 3.0, 0.2, rng)
    dt, dr = pose_difference(p, q)
    assert dt == pytest.approx(0.2) and dr == pytest.approx(3.0)


def test_perturb_trajectory_fraction_and_labels():
    cam = Camera.pinhole(64, 48, 50, 50, 31.5, 23.5)
    traj = Trajectory(tuple(Frame(str(i), cam, np.eye(4)) for i in range(20)))
    new, injected = perturb_trajectory(traj, 0.25, (1, 4), (0.05, 0.2), seed=3)
    assert len(injected) == 5
    ids = {p.frame_id for p in injected}
    for a, b in zip(traj, new, strict=False):
        dt, dr = pose_difference(a.world_from_cam, b.world_from_cam)
        assert (dt > 0) == (a.frame_id in ids)
