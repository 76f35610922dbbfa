"""The calibration estimate written exactly as a LaMAR rig session (``correct.calibration``):
read back, every frame sits where the estimate says the photo camera is."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from numpy.testing import assert_allclose

from pgt_check.correct.calibration import (
    rig_from_cam,
    with_focal_scale,
    write_calibrated_rig,
)
from pgt_check.geometry.transforms import (
    axis_angle_to_rotmat,
    invert_rigid,
    make_rigid,
    quat_to_rotmat,
)
from pgt_check.io import read_trajectory
from pgt_check.measure.record import camera_key
from pgt_check.output_layout import OUTPUTS
from pgt_check.types import Camera, Frame, Trajectory
from pgt_check.verdict.shared_results import CalibrationCheck

CAM = Camera.pinhole(640, 480, 525.0, 525.0, 319.5, 239.5)
OTHER = Camera("OPENCV", 320, 240, (250.0, 251.0, 160.1, 119.9, -0.1, 0.01, 1e-4, -2e-4))


@pytest.fixture
def random_rigid():
    rng = np.random.default_rng(3)

    def draw() -> np.ndarray:
        q = rng.normal(size=4)
        return make_rigid(quat_to_rotmat(q / np.linalg.norm(q)), rng.uniform(-5, 5, size=3))

    return draw


def _trajectory(tmp_path: Path, random_rigid) -> Trajectory:
    frames = [
        Frame(f"{10 * i}/cam", CAM if i % 3 else OTHER, random_rigid(), f"img/{i}.png",
              tmp_path / "data" / "img" / f"{i}.png", timestamp=float(10 * i))
        for i in range(6)
    ]
    return Trajectory(tuple(frames), "t.txt", "lamar")


def _estimate(status: str = "finding", translation=(0.025, -0.004, 0.001)) -> CalibrationCheck:
    r = axis_angle_to_rotmat(np.array([0.2, -0.9, 0.3]), 0.8)
    return CalibrationCheck(status=status, reason="", rotation=r.tolist(), focal_scale=0.9989,
                            translation=None if translation is None else list(translation))


def test_the_rig_session_reads_back_as_the_calibrated_cameras(tmp_path, random_rigid):
    traj = _trajectory(tmp_path, random_rigid)
    est = _estimate()
    shared = SimpleNamespace(calibration={camera_key(CAM): est,
                                          camera_key(OTHER): _estimate("passed")})
    entry = write_calibrated_rig(traj, shared, tmp_path / "out")
    assert entry is not None and list(entry.cameras) == [camera_key(CAM)]
    assert entry.to_json()["trajectory_file"] == "calibrated/trajectories.txt"
    back = read_trajectory(tmp_path / "out" / entry.trajectory_file)
    assert [f.frame_id.split("/")[0] for f in back] == [f.frame_id.split("/")[0] for f in traj]
    true_from_checked = np.eye(4)
    true_from_checked[:3, :3] = np.asarray(est.rotation)
    true_from_checked[:3, 3] = est.translation
    for given, read in zip(traj, back, strict=True):
        assert read.image_file.resolve() == given.image_file.resolve()
        if given.camera == OTHER:  # its calibration passed: written as given
            assert read.camera == OTHER
            assert_allclose(read.world_from_cam, given.world_from_cam, atol=1e-12)
            continue
        # the photo camera = the posed sensor moved by the estimate: a point x in the checked
        # camera is at true_from_checked @ x in the read one
        assert_allclose(invert_rigid(read.world_from_cam) @ given.world_from_cam,
                        true_from_checked, atol=1e-9)
        assert read.camera.focal == pytest.approx((525.0 * 0.9989, 525.0 * 0.9989))
        assert read.camera.principal_point == pytest.approx(CAM.principal_point)
    assert entry.to_json()["cameras"][camera_key(CAM)]["translation"] == pytest.approx(
        np.linalg.norm(est.translation))


def test_no_significant_estimate_removes_an_earlier_folder(tmp_path, random_rigid):
    traj = _trajectory(tmp_path, random_rigid)
    shared = SimpleNamespace(calibration={camera_key(CAM): _estimate(translation=None)})
    assert write_calibrated_rig(traj, shared, tmp_path) is not None
    assert (tmp_path / OUTPUTS.calibrated_dir / "rigs.txt").is_file()
    shared = SimpleNamespace(calibration={camera_key(CAM): _estimate("passed")})
    assert write_calibrated_rig(traj, shared, tmp_path) is None
    assert not (tmp_path / OUTPUTS.calibrated_dir).exists()
    assert write_calibrated_rig(traj, None, tmp_path) is None


def test_rig_from_cam_inverts_the_estimate_and_focal_scale_keeps_the_rest():
    est = _estimate()
    m = rig_from_cam(est)
    assert_allclose(m[:3, :3], np.asarray(est.rotation).T, atol=1e-12)
    assert_allclose(m[:3, 3], -np.asarray(est.rotation).T @ est.translation, atol=1e-12)
    with pytest.raises(ValueError, match="no rotation"):
        rig_from_cam(CalibrationCheck(status="finding", reason=""))
    scaled = with_focal_scale(OTHER, 2.0)
    assert scaled.params[:2] == (500.0, 502.0) and scaled.params[2:] == OTHER.params[2:]


def test_frames_without_an_image_keep_their_pose(tmp_path):
    """An in-memory trajectory may hold poses without images: the rig session keeps them as
    frames without one (``read_lamar``: image_missing), it does not fail the run."""
    frames = [Frame(f"{i}/cam", CAM, np.eye(4), *((f"img/{i}.png", tmp_path / f"img/{i}.png")
                                                   if i != 1 else (None, None)),
                    timestamp=float(i)) for i in range(3)]
    shared = SimpleNamespace(calibration={camera_key(CAM): _estimate()})
    entry = write_calibrated_rig(Trajectory(tuple(frames)), shared, tmp_path)
    back = read_trajectory(tmp_path / entry.trajectory_file)
    assert len(back) == 3 and [f.image_file is None for f in back] == [False, True, False]


def _evidence(camera: Camera, project, n: int = 400):
    """Measurements of ``camera`` whose evidence points (checked camera frame) are seen at
    ``project(pts_cam) -> (N, 2)`` in the photos."""
    rng = np.random.default_rng(5)
    fx, fy = camera.focal
    cx, cy = camera.principal_point
    u = rng.uniform(0, camera.width - 1, n)
    v = rng.uniform(0, camera.height - 1, n)
    z = rng.uniform(2.0, 4.0, n)
    pts = np.c_[(u - cx) / fx * z, (v - cy) / fy * z, z]
    ev = SimpleNamespace(pts_cam=pts, pts2d=project(pts))
    return [SimpleNamespace(evidence=ev, camera_id=camera_key(camera))]


def _pinhole(k: np.ndarray, x: np.ndarray) -> np.ndarray:
    return (x[:, :2] / x[:, 2:3]) @ k[:2, :2].T + k[:2, 2]


@pytest.mark.parametrize("truth", ["principal_point", "rotation"])
def test_the_written_form_is_the_one_the_evidence_fits(truth):
    """#39: a principal point 4 px off, estimated as a rotation of about 0.9 deg, is written as
    the shift fitted on the evidence (the rotation left up to 1.4 px at the image edges and its
    re-check failed); a true rotation stays a rotation."""
    from pgt_check.correct.calibration import choose_form

    cam = Camera.pinhole(320, 240, 250.0, 250.0, 163.5, 119.5)  # the photos': cx 159.5
    k_true = np.array([[250.0, 0, 159.5], [0, 250.0, 119.5], [0, 0, 1]])
    r = axis_angle_to_rotmat(np.array([0.0, 1.0, 0.0]), -np.degrees(np.arctan(3.49 / 250)))
    entry = CalibrationCheck(status="finding", reason="", rotation=r.tolist(), focal_scale=1.0)
    k = np.array([[250.0, 0, 163.5], [0, 250.0, 119.5], [0, 0, 1]])
    if truth == "principal_point":
        ms = _evidence(cam, lambda x: _pinhole(k_true, x))
    else:
        ms = _evidence(cam, lambda x: _pinhole(k, x @ r.T))
    form = choose_form(cam, entry, ms)
    assert form.form == truth
    assert form.residual_px < 0.05
    if truth == "principal_point":
        assert_allclose(form.camera.principal_point, (159.5, 119.5), atol=0.01)
        assert_allclose(form.rig_from_cam, np.eye(4), atol=1e-9)
    else:
        assert form.camera.principal_point == cam.principal_point
    assert choose_form(cam, entry).form == "rotation"  # no evidence: the estimate as it is
