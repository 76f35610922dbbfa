from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from numpy.testing import assert_allclose

from pgt_check.errors import FormatError
from pgt_check.io import read_trajectory
from pgt_check.io.nerfstudio import read_nerfstudio
from pgt_check.types import Camera

FLIP = np.diag([1.0, -1.0, -1.0, 1.0])


def write_json(directory: Path, data: dict) -> Path:
    directory.mkdir(parents=True, exist_ok=True)
    path = directory / "transforms.json"
    path.write_text(json.dumps(data, indent=2))
    return path


def test_nerfstudio_global_and_per_frame(tmp_path: Path, random_rigid) -> None:
    m0, m1 = random_rigid(), random_rigid()
    data = {
        "fl_x": 500.0,
        "fl_y": 501.0,
        "cx": 320.0,
        "cy": 240.0,
        "w": 640,
        "h": 480,
        "frames": [
            {"file_path": "images/frame_00001.png", "transform_matrix": m0.tolist()},
            {
                "file_path": "images/frame_00002.png",
                "transform_matrix": m1[:3].tolist(),
                "fl_x": 400.0,
                "fl_y": 400.0,
                "k1": -0.1,
                "k2": 0.02,
                "p1": 0.001,
                "p2": 0.0,
            },
        ],
    }
    traj = read_trajectory(write_json(tmp_path, data))
    assert traj.format == "nerfstudio"
    a, b = traj
    # OpenGL camera axes -> OpenCV: flip y and z of the camera frame
    assert_allclose(a.world_from_cam, m0 @ FLIP, atol=1e-12)
    assert_allclose(b.world_from_cam, m1 @ FLIP, atol=1e-12)
    # nerfstudio cx/cy put the top-left pixel centre at (0.5, 0.5)
    assert a.camera == Camera.pinhole(640, 480, 500.0, 501.0, 319.5, 239.5)
    assert b.camera == Camera(
        "OPENCV", 640, 480, (400.0, 400.0, 319.5, 239.5, -0.1, 0.02, 0.001, 0.0)
    )
    assert a.frame_id == a.image_path == "images/frame_00001.png"
    assert a.image_file == tmp_path / "images/frame_00001.png"


def test_opengl_axes_numbers(tmp_path: Path) -> None:
    """An identity OpenGL cam-to-world looks down -z with y up: in OpenCV z points to -z, y to -y."""
    data = {
        "fl_x": 50,
        "w": 64,
        "h": 48,
        "frames": [{"file_path": "a.png", "transform_matrix": np.eye(4).tolist()}],
    }
    frame = read_nerfstudio(write_json(tmp_path, data))[0]
    assert_allclose(frame.world_from_cam[:3, 2], [0, 0, -1])  # viewing direction
    assert_allclose(frame.world_from_cam[:3, 1], [0, -1, 0])  # image down
    assert frame.camera.principal_point == (31.5, 23.5)  # default centre w/2, h/2 minus 0.5


def test_instant_ngp_camera_angle(tmp_path: Path, make_image) -> None:
    make_image(tmp_path / "train" / "r_0.png", 80, 60)
    angle = 0.6911112070083618
    data = {
        "camera_angle_x": angle,
        "frames": [{"file_path": "./train/r_0", "transform_matrix": np.eye(4).tolist()}],
    }
    write_json(tmp_path, data)
    frame = read_nerfstudio(tmp_path)[0]  # a folder holding transforms.json
    fx = 0.5 * 80 / math.tan(0.5 * angle)
    assert frame.camera == Camera.pinhole(80, 60, fx, fx, 39.5, 29.5)
    assert frame.image_file == tmp_path / "train" / "r_0.png"
    assert frame.image_path == "./train/r_0"


GOOD_FRAME = {"file_path": "a.png", "transform_matrix": np.eye(4).tolist()}
BAD = {
    "no-frames": ({"fl_x": 1}, "'frames' list"),
    "empty-frames": ({"frames": []}, "at least one entry"),
    "matrix-shape": (
        {
            "fl_x": 5,
            "w": 8,
            "h": 6,
            "frames": [{"file_path": "a.png", "transform_matrix": [[1, 0], [0, 1]]}],
        },
        "frames[0]: expected a 4x4",
    ),
    "matrix-scaled": (
        {
            "fl_x": 5,
            "w": 8,
            "h": 6,
            "frames": [{"file_path": "a.png", "transform_matrix": (2 * np.eye(4)).tolist()}],
        },
        "rigid",
    ),
    "no-focal": ({"w": 8, "h": 6, "frames": [GOOD_FRAME]}, "'fl_x' or 'camera_angle_x'"),
    "no-size": ({"fl_x": 5, "frames": [GOOD_FRAME]}, "expected 'w' and 'h'"),
    "fisheye": (
        {"camera_model": "OPENCV_FISHEYE", "fl_x": 5, "w": 8, "h": 6, "frames": [GOOD_FRAME]},
        "camera_model",
    ),
    "text-focal": (
        {"fl_x": "five", "w": 8, "h": 6, "frames": [GOOD_FRAME]},
        "finite number for 'fl_x'",
    ),
    "no-file-path": (
        {"fl_x": 5, "w": 8, "h": 6, "frames": [{"transform_matrix": np.eye(4).tolist()}]},
        "'file_path'",
    ),
    "duplicate": (
        {"fl_x": 5, "w": 8, "h": 6, "frames": [GOOD_FRAME, GOOD_FRAME]},
        "frames[1]: expected unique",
    ),
}


@pytest.mark.parametrize("case", list(BAD), ids=list(BAD))
def test_malformed(tmp_path: Path, case: str, check_error) -> None:
    data, fragment = BAD[case]
    path = write_json(tmp_path, data)
    with pytest.raises(FormatError) as info:
        read_nerfstudio(path)
    check_error(info.value, path, None, fragment)


def test_invalid_json_line_number(tmp_path: Path, check_error) -> None:
    path = tmp_path / "transforms.json"
    path.write_text('{\n  "frames": [\n    {"file_path": "a.png",,}\n  ]\n}\n')
    with pytest.raises(FormatError) as info:
        read_nerfstudio(path)
    check_error(info.value, path, 3, "expected valid JSON")


def test_dataparser_transform_round_trip(tmp_path: Path, random_rigid) -> None:
    """Poses exported in a trained model's frame (scale * (T @ M)) come back as M."""
    originals = [random_rigid() for _ in range(3)]
    transform, scale = random_rigid(), 0.37
    frames = []
    for i, m in enumerate(originals):
        stored = transform @ m
        stored[:3, 3] *= scale  # nerfstudio's auto_scale_poses
        frames.append({"file_path": f"f{i}.png", "transform_matrix": stored.tolist()})
    data = {"fl_x": 50.0, "w": 64, "h": 48, "frames": frames}
    path = write_json(tmp_path / "ns", data)
    dp = tmp_path / "ns" / "dataparser_transforms.json"
    dp.write_text(json.dumps({"transform": transform[:3].tolist(), "scale": scale}))
    traj = read_trajectory(path, dataparser_transforms=dp)
    for frame, m in zip(traj, originals, strict=True):
        assert_allclose(frame.world_from_cam, m @ FLIP, atol=1e-9)
    assert traj.metadata["dataparser_transforms"] == str(dp)
    # without the option the poses stay in the dataparser frame
    plain = read_nerfstudio(path)
    assert not np.allclose(plain[0].world_from_cam, originals[0] @ FLIP, atol=1e-3)
    # a transform that is not rigid, or a bad scale, is a FormatError
    dp.write_text(json.dumps({"transform": (2 * transform[:3]).tolist(), "scale": scale}))
    with pytest.raises(FormatError, match="rotation"):
        read_nerfstudio(path, dataparser_transforms=dp)
    dp.write_text(json.dumps({"transform": transform[:3].tolist(), "scale": 0}))
    with pytest.raises(FormatError, match="positive 'scale'"):
        read_nerfstudio(path, dataparser_transforms=dp)
