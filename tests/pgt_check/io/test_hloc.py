"""hloc results.txt: cam_from_world rows, intrinsics from a camera, a COLMAP model or a query list."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from numpy.testing import assert_allclose

from pgt_check.errors import FormatError, InputError
from pgt_check.geometry.transforms import invert_rigid, rotmat_to_quat
from pgt_check.io import detect_format, read_trajectory
from pgt_check.io.hloc import read_hloc
from pgt_check.types import Camera


def write_results(path: Path, names: list[str], cam_from_worlds: list[np.ndarray]) -> Path:
    rows = []
    for name, m in zip(names, cam_from_worlds, strict=True):
        values = (*rotmat_to_quat(m[:3, :3]), *m[:3, 3])
        rows.append(name + " " + " ".join(repr(float(v)) for v in values))
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(rows) + "\n")
    return path


def write_colmap_model(directory: Path, names: list[str]) -> Path:
    """Two cameras, one image per name (alternating cameras), identity poses."""
    directory.mkdir(parents=True, exist_ok=True)
    (directory / "cameras.txt").write_text(
        "1 SIMPLE_RADIAL 640 480 500 320 240 0.01\n2 PINHOLE 64 48 50 51 32 24\n"
    )
    rows = [f"{i + 1} 1 0 0 0 0 0 0 {i % 2 + 1} {n}\n" for i, n in enumerate(names)]
    (directory / "images.txt").write_text("\n".join(rows) + "\n")
    (directory / "points3D.txt").write_text("")
    return directory


NAMES = ["query/day/a.jpg", "query/night/b.jpg"]


def test_hloc_with_a_given_camera(tmp_path: Path, random_rigid) -> None:
    poses = [random_rigid() for _ in NAMES]
    path = write_results(tmp_path / "results.txt", NAMES, poses)
    assert detect_format(path) == "hloc"
    traj = read_trajectory(path, camera="PINHOLE,640,480,500,500,320,240")
    assert traj.format == "hloc" and [f.frame_id for f in traj] == NAMES
    for frame, cam_from_world in zip(traj, poses, strict=True):
        assert_allclose(frame.world_from_cam, invert_rigid(cam_from_world), atol=1e-9)
        assert frame.camera == Camera.pinhole(640, 480, 500, 500, 319.5, 239.5)
    assert traj[1].image_file == tmp_path / "query/night/b.jpg"


def test_hloc_intrinsics_from_a_colmap_model(tmp_path: Path, random_rigid) -> None:
    path = write_results(tmp_path / "results.txt", NAMES, [random_rigid() for _ in NAMES])
    model = write_colmap_model(tmp_path / "proj" / "sparse" / "0", NAMES)
    traj = read_hloc(path, sensors=tmp_path / "proj")  # a project root is descended into
    assert traj[0].camera == Camera("SIMPLE_RADIAL", 640, 480, (500, 319.5, 239.5, 0.01))
    assert traj[1].camera == Camera.pinhole(64, 48, 50, 51, 31.5, 23.5)
    # a name the model lacks: FormatError with its line (two cameras: no fallback)
    other = write_results(tmp_path / "other.txt", ["x.jpg"], [random_rigid()])
    with pytest.raises(FormatError, match=r"other.txt:1: .*'x.jpg'"):
        read_hloc(other, sensors=model)


def test_hloc_intrinsics_from_a_query_list(tmp_path: Path, random_rigid) -> None:
    path = write_results(tmp_path / "results.txt", NAMES, [random_rigid() for _ in NAMES])
    queries = tmp_path / "queries_with_intrinsics.txt"
    queries.write_text(
        "query/day/a.jpg SIMPLE_RADIAL 1024 768 900 512 384 -0.02\n"
        "query/night/b.jpg OPENCV_FISHEYE 640 480 300 301 320 240 0.1 0 0 0\n"
    )
    traj = read_trajectory(path, "hloc", sensors=queries)
    assert traj[0].camera == Camera("SIMPLE_RADIAL", 1024, 768, (900, 511.5, 383.5, -0.02))
    assert traj[1].camera.model == "OPENCV_FISHEYE"


def test_hloc_errors(tmp_path: Path, random_rigid) -> None:
    path = write_results(tmp_path / "results.txt", NAMES, [random_rigid() for _ in NAMES])
    with pytest.raises(InputError, match="store no intrinsics"):
        read_hloc(path)
    with pytest.raises(InputError, match="not both"):
        read_hloc(path, camera="PINHOLE,64,48,50,50,32,24", sensors=path)
    dup = tmp_path / "dup.txt"
    dup.write_text(path.read_text() + path.read_text().splitlines()[0] + "\n")
    with pytest.raises(FormatError, match=r"dup.txt:3: expected unique image names"):
        read_hloc(dup, camera="PINHOLE,64,48,50,50,32,24")
    bad = tmp_path / "bad.txt"
    bad.write_text("a.jpg 1 0 0 0 1 2\n")
    with pytest.raises(FormatError, match="expected 8 fields"):
        read_hloc(bad, camera="PINHOLE,64,48,50,50,32,24")
    with pytest.raises(InputError, match="--dataparser-transforms applies to nerfstudio"):
        read_trajectory(path, dataparser_transforms=tmp_path / "x.json")
