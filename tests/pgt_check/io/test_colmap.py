from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from numpy.testing import assert_allclose

from pgt_check.errors import FormatError, InputError
from pgt_check.geometry.transforms import invert_rigid, rotmat_to_quat
from pgt_check.io import detect_format, read_trajectory
from pgt_check.io.colmap import read_colmap
from pgt_check.types import Camera

CAMERAS = "# Camera list\n1 PINHOLE 640 480 500 510 320.5 240.5\n2 SIMPLE_RADIAL 320 240 300 160 120 0.01\n"


def write_text_model(
    directory: Path, cam_from_worlds: list[np.ndarray], cameras: str = CAMERAS
) -> Path:
    """A COLMAP text model written by hand: one image per pose, alternating camera ids 1, 2."""
    directory.mkdir(parents=True, exist_ok=True)
    (directory / "cameras.txt").write_text(cameras)
    rows = ["# Image list"]
    for i, cam_from_world in enumerate(cam_from_worlds):
        q = rotmat_to_quat(cam_from_world[:3, :3])
        t = cam_from_world[:3, 3]
        values = " ".join(repr(float(v)) for v in (*q, *t))
        rows += [f"{i + 1} {values} {i % 2 + 1} img_{i:02d}.png", ""]
    (directory / "images.txt").write_text("\n".join(rows) + "\n")
    (directory / "points3D.txt").write_text("# 3D point list\n")
    return directory


def test_text_model(tmp_path: Path, random_rigid) -> None:
    poses = [random_rigid() for _ in range(4)]
    model = write_text_model(tmp_path / "sparse", poses)
    (tmp_path / "images").mkdir()
    traj = read_colmap(model)
    assert traj.format == "colmap"
    assert [f.frame_id for f in traj] == [f"img_{i:02d}.png" for i in range(4)]
    for frame, cam_from_world in zip(traj, poses, strict=True):
        assert_allclose(frame.world_from_cam, invert_rigid(cam_from_world), atol=1e-10)
        assert_allclose(frame.cam_from_world, cam_from_world, atol=1e-10)
        assert frame.image_file == tmp_path / "images" / frame.image_path
    # COLMAP pixel convention in the file (320.5, 240.5) -> OpenCV (320, 240)
    assert traj[0].camera == Camera.pinhole(640, 480, 500.0, 510.0, 320.0, 240.0)
    assert traj[1].camera == Camera("SIMPLE_RADIAL", 320, 240, (300.0, 159.5, 119.5, 0.01))


def test_known_pose_numbers(tmp_path: Path) -> None:
    """cam_from_world = identity rotation, t = (1, 2, 3): the camera centre is (-1, -2, -3)."""
    model = tmp_path / "m"
    model.mkdir()
    (model / "cameras.txt").write_text(CAMERAS)
    (model / "images.txt").write_text("1 1 0 0 0 1 2 3 1 a.png\n\n")
    (model / "points3D.txt").write_text("")
    traj = read_colmap(model)
    assert_allclose(traj[0].center, [-1, -2, -3])


def test_binary_model_and_file_path(tmp_path: Path, random_rigid) -> None:
    import pycolmap

    poses = [random_rigid() for _ in range(3)]
    text = write_text_model(tmp_path / "text", poses)
    binary = tmp_path / "bin"
    binary.mkdir()
    pycolmap.Reconstruction(str(text)).write_binary(str(binary))
    assert (binary / "cameras.bin").is_file()
    assert detect_format(binary) == "colmap"
    assert detect_format(binary / "images.bin") == "colmap"
    a, b = read_colmap(text), read_trajectory(binary / "images.bin")
    assert [f.frame_id for f in a] == [f.frame_id for f in b]
    for fa, fb in zip(a, b, strict=True):
        assert_allclose(fa.world_from_cam, fb.world_from_cam, atol=1e-12)
        assert fa.camera == fb.camera
    assert b[0].image_file == binary / b[0].image_path  # no ../images: the model dir


def test_images_option(tmp_path: Path, random_rigid) -> None:
    model = write_text_model(tmp_path / "m", [random_rigid()])
    (tmp_path / "photos").mkdir()
    traj = read_trajectory(model, images=tmp_path / "photos")
    assert traj[0].image_file == tmp_path / "photos" / "img_00.png"
    with pytest.raises(InputError, match="not found"):
        read_colmap(model, images=tmp_path / "missing")


def test_sparse_zero_layout_finds_project_images(tmp_path: Path, random_rigid) -> None:
    model = write_text_model(tmp_path / "sparse" / "0", [random_rigid()])
    (tmp_path / "images").mkdir()
    assert read_colmap(model)[0].image_file == tmp_path / "images" / "img_00.png"


def test_fisheye_camera_model_is_read(tmp_path: Path, random_rigid) -> None:
    cameras = "1 OPENCV_FISHEYE 640 480 500 510 320 240 0.1 0.01 0 0\n"
    model = write_text_model(tmp_path / "m", [random_rigid()], cameras=cameras)
    cam = read_colmap(model)[0].camera
    assert cam == Camera("OPENCV_FISHEYE", 640, 480, (500, 510, 319.5, 239.5, 0.1, 0.01, 0, 0))
    assert cam.is_distorted


def test_unsupported_camera_model(tmp_path: Path, random_rigid, check_error) -> None:
    cameras = "1 EQUIRECTANGULAR 640 480 640 480\n2 PINHOLE 64 48 50 50 32 24\n"
    model = write_text_model(tmp_path / "m", [random_rigid()], cameras=cameras)
    with pytest.raises(FormatError) as info:
        read_colmap(model)
    check_error(info.value, model / "cameras.txt", None, "'EQUIRECTANGULAR'")


def test_corrupt_model(tmp_path: Path) -> None:
    model = tmp_path / "m"
    model.mkdir()
    (model / "cameras.txt").write_text("1 PINHOLE 640 480 500\n")
    (model / "images.txt").write_text("")
    (model / "points3D.txt").write_text("")
    with pytest.raises(FormatError, match="COLMAP model"):
        read_colmap(model)


def test_not_a_model(tmp_path: Path) -> None:
    with pytest.raises(FormatError, match="cameras.txt or cameras.bin"):
        read_colmap(tmp_path)
    with pytest.raises(InputError, match="not found"):
        read_colmap(tmp_path / "nope")


def test_project_root_is_descended_into(tmp_path: Path, random_rigid) -> None:
    """A COLMAP project (images/, sparse/0/, sparse/1/) given by its root: sparse/0 is read."""
    poses = [random_rigid() for _ in range(2)]
    write_text_model(tmp_path / "proj" / "sparse" / "0", poses)
    write_text_model(tmp_path / "proj" / "sparse" / "1", [random_rigid()])
    (tmp_path / "proj" / "images").mkdir()
    assert detect_format(tmp_path / "proj") == "colmap"
    traj = read_trajectory(tmp_path / "proj")
    assert traj.source == str(tmp_path / "proj" / "sparse" / "0") and len(traj) == 2
    assert_allclose(traj[0].world_from_cam, invert_rigid(poses[0]), atol=1e-9)
    assert traj[0].image_file == tmp_path / "proj" / "images" / "img_00.png"
    # an unnumbered sparse/ works too; a folder without a model is not COLMAP
    write_text_model(tmp_path / "flat" / "sparse", poses)
    assert read_colmap(tmp_path / "flat").source == str(tmp_path / "flat" / "sparse")
    (tmp_path / "empty" / "sparse" / "0").mkdir(parents=True)
    with pytest.raises(FormatError, match="sparse/0"):
        read_colmap(tmp_path / "empty")


@pytest.mark.parametrize("size", ["-640 480", "640 0", "0 480", "640 -1"])
def test_camera_size_not_positive_names_file_and_line(tmp_path: Path, size: str) -> None:
    """A negative or zero width / height is a FormatError naming cameras.txt and the line
    (pycolmap reads a negative size as a huge unsigned one: every frame was UNVERIFIABLE)."""
    model = tmp_path / "m"
    model.mkdir()
    (model / "cameras.txt").write_text(f"# Camera list\n1 PINHOLE {size} 500 500 320 240\n")
    (model / "images.txt").write_text("1 1 0 0 0 0 0 0 1 a.png\n\n")
    (model / "points3D.txt").write_text("")
    with pytest.raises(FormatError, match=r"cameras\.txt:2: camera 1: expected a positive"):
        read_colmap(model)
