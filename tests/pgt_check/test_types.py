import numpy as np
import pytest

from pgt_check.types import Camera, Frame, Trajectory


def test_camera_K_and_scaling_keeps_pixel_centres():
    cam = Camera.pinhole(640, 480, 500, 510, 319.5, 239.5)
    np.testing.assert_allclose(cam.K, [[500, 0, 319.5], [0, 510, 239.5], [0, 0, 1]])
    half = cam.scaled(0.5)
    assert (half.width, half.height) == (320, 240)
    # the image centre stays the image centre: (319.5 + .5) * .5 - .5 = 159.5
    assert half.principal_point == pytest.approx((159.5, 119.5))
    assert half.focal == pytest.approx((250, 255))


def test_camera_rejects_bad_values():
    with pytest.raises(ValueError, match="unknown camera model"):
        Camera("FISHEYE_X", 10, 10, (1, 2, 3))
    with pytest.raises(ValueError, match="takes 4 parameters"):
        Camera("PINHOLE", 10, 10, (1, 2, 3))
    with pytest.raises(ValueError, match="positive"):
        Camera.pinhole(10, 10, -1, 1, 5, 5)
    with pytest.raises(ValueError, match="finite"):
        Camera.pinhole(10, 10, np.nan, 1, 5, 5)


def test_distortion_and_colmap_params():
    cam = Camera("OPENCV", 100, 80, (90, 91, 49.5, 39.5, 0.1, 0.0, 0.0, 0.0))
    assert cam.is_distorted and not cam.as_pinhole().is_distorted
    assert cam.to_colmap_params()[2:4] == (50.0, 40.0)


def test_frame_validates_pose():
    cam = Camera.pinhole(64, 48, 50, 50, 31.5, 23.5)
    with pytest.raises(ValueError, match="shape"):
        Frame("a", cam, np.eye(3))
    bad = np.eye(4)
    bad[0, 0] = 2
    with pytest.raises(ValueError, match="not a rotation"):
        Frame("a", cam, bad)
    refl = np.diag([1.0, 1.0, -1.0, 1.0])
    with pytest.raises(ValueError, match="not a rotation"):
        Frame("a", cam, refl)
    f = Frame("a", cam, np.eye(4))
    assert not f.world_from_cam.flags.writeable


def test_trajectory_rejects_duplicate_ids():
    cam = Camera.pinhole(64, 48, 50, 50, 31.5, 23.5)
    with pytest.raises(ValueError, match="duplicate"):
        Trajectory((Frame("a", cam, np.eye(4)), Frame("a", cam, np.eye(4))))
