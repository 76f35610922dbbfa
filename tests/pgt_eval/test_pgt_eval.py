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


def test_perturb_runs_places_contiguous_runs_of_wrong_frames():
    from pgt_eval import perturb_runs

    cam = Camera.pinhole(64, 48, 50, 50, 31.5, 23.5)
    traj = Trajectory(tuple(Frame(str(i), cam, np.eye(4)) for i in range(30)))
    new, injected = perturb_runs(traj, 0.4, (0.5, 4), (0.01, 0.08), run_length=(2, 4), seed=1)
    assert len(injected) == 12
    wrong = [i for i, (a, b) in enumerate(zip(traj, new, strict=True))
             if pose_difference(a.world_from_cam, b.world_from_cam)[1] > 0]
    assert wrong == sorted(int(p.frame_id) for p in injected)
    runs, cur = [], [wrong[0]]
    for i in wrong[1:]:
        if i == cur[-1] + 1:
            cur.append(i)
        else:
            runs.append(cur)
            cur = [i]
    runs.append(cur)
    # every wrong frame has a wrong neighbour except where the count left a shorter last run
    assert sum(len(r) >= 2 for r in runs) >= len(runs) - 1
    assert all(len(r) <= 4 for r in runs)
    for p in injected:
        assert 0.5 <= p.rotation_deg <= 4 and 0.01 <= p.translation <= 0.08
