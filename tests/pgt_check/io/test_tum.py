from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import pytest
from numpy.testing import assert_allclose

from pgt_check.errors import FormatError, InputError
from pgt_check.geometry.transforms import axis_angle_to_rotmat, rotmat_to_quat
from pgt_check.io import read_trajectory
from pgt_check.io.tum import read_tum, stem_timestamp
from pgt_check.types import Camera

SPEC = "PINHOLE,64,48,50,50,32,24"


def tum_row(stamp: str, world_from_cam: np.ndarray) -> str:
    w, x, y, z = rotmat_to_quat(world_from_cam[:3, :3])
    t = world_from_cam[:3, 3]
    return " ".join([stamp, *(repr(float(v)) for v in (*t, x, y, z, w))])


def touch(folder: Path, *names: str) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    for name in names:
        (folder / name).write_bytes(b"")
    return folder


def test_float_timestamps_nearest_match(tmp_path: Path, random_rigid, caplog) -> None:
    stamps = ["1305031102.175304", "1305031102.211214", "1305031102.243211", "1305031109.0"]
    poses = [random_rigid() for _ in stamps]
    path = tmp_path / "groundtruth.txt"
    path.write_text("# ground truth\n" + "\n".join(map(tum_row, stamps, poses)) + "\n")
    # images 5 ms off the poses (within 20 ms); the last pose has no image
    images = touch(
        tmp_path / "rgb",
        "1305031102.180000.png",
        "1305031102.206000.png",
        "1305031102.250000.png",
        "notes.png",
    )
    with caplog.at_level(logging.WARNING, logger="pgt_check.io.tum"):
        traj = read_tum(path, camera=SPEC, images=images)
    # the pose without an image stays, without an image (UNVERIFIABLE image_missing; #25)
    assert [f.frame_id for f in traj] == stamps
    assert [f.image_path for f in traj] == [
        "1305031102.180000.png",
        "1305031102.206000.png",
        "1305031102.250000.png",
        "",
    ]
    assert traj[3].image_file is None
    for frame, pose in zip(traj, poses, strict=True):
        assert_allclose(frame.world_from_cam, pose, atol=1e-12)
    assert traj[0].timestamp == pytest.approx(1305031102.175304)
    assert any("1 of 4 pose(s) have no image" in r.getMessage() for r in caplog.records)
    # a tighter tolerance drops everything that is 5 ms off
    with pytest.raises(InputError, match="no pose matched"):
        read_tum(path, camera=SPEC, images=images, max_time_diff=0.001)


def test_integer_timestamps_match_exactly(tmp_path: Path, random_rigid) -> None:
    path = tmp_path / "traj.txt"
    path.write_text("\n".join(tum_row(s, random_rigid()) for s in ("0", "10", "11")) + "\n")
    images = touch(tmp_path / "images", "frame-000000.color.jpg", "frame-000010.color.jpg")
    traj = read_tum(path, camera=SPEC, images=images)
    # 11 is within 0.02 s of nothing and is an integer: no match with frame 10 (kept without
    # an image: UNVERIFIABLE image_missing)
    assert [(f.frame_id, f.image_path) for f in traj] == [
        ("0", "frame-000000.color.jpg"),
        ("10", "frame-000010.color.jpg"),
        ("11", ""),
    ]


def test_pose_convention_and_camera(tmp_path: Path) -> None:
    """TUM stores world_from_cam with (qx, qy, qz, qw): scalar last."""
    r = axis_angle_to_rotmat([0, 1, 0], 30)
    w, x, y, z = (float(v) for v in rotmat_to_quat(r))
    path = tmp_path / "t.txt"
    path.write_text(f"5 1 2 3 {x!r} {y!r} {z!r} {w!r}\n")
    touch(tmp_path / "images", "5.png")
    traj = read_trajectory(path, camera=SPEC)  # images/ beside the file is the default
    assert_allclose(traj[0].world_from_cam[:3, :3], r, atol=1e-12)
    assert_allclose(traj[0].center, [1, 2, 3])
    assert traj[0].camera == Camera.pinhole(64, 48, 50, 50, 31.5, 23.5)  # spec is COLMAP convention


def test_list_file(tmp_path: Path, random_rigid) -> None:
    path = tmp_path / "gt.txt"
    path.write_text(tum_row("1.50", random_rigid()) + "\n" + tum_row("2.0", random_rigid()) + "\n")
    (tmp_path / "rgb.txt").write_text("# timestamp filename\n1.5 rgb/1.5.png\n2.01 rgb/2.01.png\n")
    traj = read_tum(path, camera=Camera.pinhole(64, 48, 50, 50, 31.5, 23.5))  # rgb.txt beside
    assert [f.frame_id for f in traj] == ["1.50", "2.0"]
    assert traj[1].image_path == "rgb/2.01.png"
    assert traj[1].image_file == tmp_path / "rgb/2.01.png"


def test_camera_required(tmp_path: Path, random_rigid) -> None:
    path = tmp_path / "t.txt"
    path.write_text(tum_row("0", random_rigid()) + "\n")
    with pytest.raises(InputError, match="--camera is required"):
        read_trajectory(path)


def test_no_images(tmp_path: Path, random_rigid) -> None:
    path = tmp_path / "t.txt"
    path.write_text(tum_row("0", random_rigid()) + "\n")
    with pytest.raises(InputError, match="no images given"):
        read_tum(path, camera=SPEC)


def test_ambiguous_folder(tmp_path: Path, random_rigid) -> None:
    path = tmp_path / "t.txt"
    path.write_text(tum_row("0", random_rigid()) + "\n")
    images = touch(tmp_path / "images", "frame-000000.color.png", "frame-000000.depth.png")
    with pytest.raises(InputError, match="two images for timestamp"):
        read_tum(path, camera=SPEC, images=images)


@pytest.mark.parametrize(
    ("name", "expected"),
    [
        ("1305031102.175304.png", "1305031102.175304"),
        ("frame-000010.color.jpg", "000010"),
        ("rgb_0042.png", "0042"),
        ("seq1_frame7.png", "7"),
        ("nonumber.png", None),
    ],
)
def test_stem_timestamp(name: str, expected: str | None) -> None:
    assert stem_timestamp(name) == expected


BAD = {
    "columns": ("0 1 2 3 0 0 0\n", 1, "expected 8 fields"),
    "number": ("# c\n0 1 2 x 0 0 0 1\n", 2, "expected a number for tz"),
    "quaternion": ("0 1 2 3 0 0 0 2\n", 1, "unit quaternion"),
    "duplicate": ("0 1 2 3 0 0 0 1\n0.0 1 2 3 0 0 0 1\n", 2, "unique timestamps"),
    "empty": ("# only a comment\n", 1, "at least one data row"),
}


@pytest.mark.parametrize("case", list(BAD), ids=list(BAD))
def test_malformed(tmp_path: Path, case: str, check_error) -> None:
    content, line, fragment = BAD[case]
    path = tmp_path / "traj.txt"
    path.write_text(content)
    touch(tmp_path / "images", "0.png")
    with pytest.raises(FormatError) as info:
        read_tum(path, camera=SPEC)
    check_error(info.value, path, line, fragment)


def test_malformed_list_file(tmp_path: Path, random_rigid, check_error) -> None:
    path = tmp_path / "t.txt"
    path.write_text(tum_row("0", random_rigid()) + "\n")
    (tmp_path / "rgb.txt").write_text("# h\n0 a.png extra\n")
    with pytest.raises(FormatError) as info:
        read_tum(path, camera=SPEC)
    check_error(info.value, tmp_path / "rgb.txt", 2, "expected 2 fields")


@pytest.mark.shared_data
def test_real_tum_equals_lamar(shared_data: Path) -> None:
    scene = shared_data / "7scenes_redkitchen"
    tum = read_trajectory(
        scene / "trajectory_tum.txt",
        camera="PINHOLE,640,480,525,525,320,240",
        images=scene / "images",
    )
    lamar = read_trajectory(scene / "trajectories.txt")
    assert len(tum) == len(lamar) == 100
    for a, b in zip(tum, lamar, strict=True):
        assert a.image_file == b.image_file
        assert a.camera == b.camera
        assert_allclose(a.world_from_cam, b.world_from_cam, atol=1e-12)
