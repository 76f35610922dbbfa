import numpy as np
import pytest

from pgt_check.geometry.pnp import estimate_pose_correction, lift_keypoints
from pgt_check.geometry.transforms import apply_rigid, invert_rigid, pose_difference
from pgt_check.io import read_trajectory
from pgt_check.match import make_matcher
from pgt_check.render import load_mesh, make_renderer
from pgt_eval import perturb_pose


def test_lift_keypoints_back_projects_exactly():
    from pgt_check.types import Camera

    cam = Camera.pinhole(40, 30, 50, 50, 19.5, 14.5)
    depth = np.full((30, 40), 2.0, np.float32)
    depth[:, 30:] = 0
    kp = np.array([[19.5, 14.5], [5.0, 5.0], [35.0, 5.0]])
    pose = np.eye(4)
    pose[:3, 3] = [1e6, 0, 0]
    valid, pts = lift_keypoints(kp, depth, cam, pose)
    assert valid.tolist() == [True, True, False]
    np.testing.assert_allclose(pts[0], [1e6, 0, 2.0])
    np.testing.assert_allclose(pts[1], [1e6 + (5 - 19.5) / 50 * 2, (5 - 14.5) / 50 * 2, 2.0])


@pytest.mark.parametrize("rot,trans", [(2.0, 0.0), (0.0, 0.15), (1.5, 0.1)])
def test_pnp_recovers_a_synthetic_pose_offset(sample_scene, rot, trans):
    traj = read_trajectory(sample_scene / "trajectories.txt")
    r = make_renderer(load_mesh(sample_scene / "mesh.glb"))
    f = traj.frames[5]
    cam = f.camera
    true = f.world_from_cam
    wrong = perturb_pose(true, rot, trans, np.random.default_rng(1))
    render = r.render(cam, wrong)  # the pose under test
    photo = r.render(cam, true).rgb  # what the camera really saw
    r.close()
    m = make_matcher("sift").match(render.rgb, photo, mask0=render.coverage)
    corr = estimate_pose_correction(m.kpts0, m.kpts1, render.depth, cam, wrong)
    assert corr.success, corr.reason
    dt, dr = pose_difference(true, corr.world_from_cam)
    assert dt < 0.02 and dr < 0.2  # the estimate lands on the true pose
    assert corr.drot_deg == pytest.approx(rot, abs=0.3 * max(rot, 0.5))
    assert corr.dt == pytest.approx(trans, abs=0.3 * max(trans, 0.05))


def test_pnp_with_too_few_points_fails_cleanly():
    from pgt_check.types import Camera

    cam = Camera.pinhole(40, 30, 50, 50, 19.5, 14.5)
    corr = estimate_pose_correction(np.zeros((3, 2)), np.zeros((3, 2)), np.ones((30, 40)), cam,
                                    np.eye(4))
    assert not corr.success and corr.reason == "too_few_3d_points"


def test_invert_sanity():
    p = np.eye(4)
    p[:3, 3] = [1, 2, 3]
    np.testing.assert_allclose(apply_rigid(invert_rigid(p), np.array([[1.0, 2, 3]])), [[0, 0, 0]])
