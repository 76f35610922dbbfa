from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from numpy.testing import assert_allclose

from pgt_check.errors import FormatError, InputError
from pgt_check.geometry.transforms import axis_angle_to_rotmat, make_rigid, quat_to_rotmat
from pgt_check.io import read_trajectory, write_lamar
from pgt_check.io.lamar import read_lamar
from pgt_check.types import Camera, Frame, Trajectory

SENSORS = "# sensor_id, name, sensor_type, [sensor_params]+\ncam0, rgb, camera, PINHOLE, 640, 480, 500, 510, 320, 240\n"
IMAGES = "# timestamp, sensor_id, image_path\n0, cam0, images/a.jpg\n10, cam0, images/b.jpg\n"
TRAJ = (
    "# timestamp, device_id, qw, qx, qy, qz, tx, ty, tz\n"
    "0, cam0, 1, 0, 0, 0, 1, 2, 3\n"
    "10, cam0, 0.7071067811865476, 0.7071067811865476, 0, 0, 4, 5, 6\n"
)


def write_session(directory: Path, **files: str) -> Path:
    """Write sensors/images/trajectories (overridable by keyword, None = omit) and return the trajectories path."""
    contents = {"sensors.txt": SENSORS, "images.txt": IMAGES, "trajectories.txt": TRAJ}
    contents.update({k.replace("__", "."): v for k, v in files.items()})
    directory.mkdir(parents=True, exist_ok=True)
    for name, text in contents.items():
        if text is not None:
            (directory / name).write_text(text)
    return directory / "trajectories.txt"


def test_read_basic(tmp_path: Path) -> None:
    traj = read_lamar(write_session(tmp_path))
    assert [f.frame_id for f in traj] == ["0/cam0", "10/cam0"]
    assert traj.format == "lamar"
    first, second = traj
    assert_allclose(first.world_from_cam, make_rigid(np.eye(3), [1, 2, 3]), atol=1e-12)
    # world_from_cam as stored: rotation of 90 deg about x, translation = camera centre
    assert_allclose(second.world_from_cam[:3, :3], axis_angle_to_rotmat([1, 0, 0], 90), atol=1e-12)
    assert_allclose(second.center, [4, 5, 6])
    assert first.image_path == "images/a.jpg"
    assert first.image_file == tmp_path / "images/a.jpg"
    assert first.timestamp == 0.0 and second.timestamp == 10.0


def test_principal_point_half_pixel_shift(tmp_path: Path) -> None:
    """LaMAR/COLMAP cx=320 (top-left pixel centre at 0.5) is OpenCV cx=319.5; the writer adds it back."""
    traj = read_lamar(write_session(tmp_path / "in"))
    cam = traj[0].camera
    assert cam.principal_point == (319.5, 239.5)
    assert cam.focal == (500.0, 510.0)
    assert_allclose(cam.K, [[500, 0, 319.5], [0, 510, 239.5], [0, 0, 1]])
    written = write_lamar(traj, tmp_path / "out")
    row = written["sensors"].read_text().splitlines()[1]
    assert [float(v) for v in row.split(",")[6:]] == [500.0, 510.0, 320.0, 240.0]


def test_whitespace_and_comments_tolerated(tmp_path: Path) -> None:
    traj_text = (
        "# header\n\n  0 ,cam0,1,0,0,0 , 1,2,3  \n# a comment\n10,cam0, 1, 0, 0, 0, 0, 0, 0\n"
    )
    traj = read_lamar(write_session(tmp_path, trajectories__txt=traj_text))
    assert len(traj) == 2


def test_round_trip(tmp_path: Path, random_rigid, make_image) -> None:
    cams = [
        Camera.pinhole(640, 480, 500.0, 505.0, 319.25, 240.75),
        Camera("OPENCV", 320, 240, (250.0, 251.0, 160.1, 119.9, -0.1, 0.01, 1e-4, -2e-4)),
    ]
    frames = [
        Frame(
            f"f{i}",
            cams[i % 2],
            random_rigid(),
            f"img/{i}.png",
            tmp_path / "data" / "img" / f"{i}.png",
            timestamp=float(100 * i),
        )
        for i in range(6)
    ]
    original = Trajectory(tuple(frames))
    write_lamar(original, tmp_path / "data", suffix="_x")
    back = read_trajectory(tmp_path / "data" / "trajectories_x.txt")
    assert len(back) == len(original)
    for a, b in zip(original, back, strict=True):
        assert_allclose(b.world_from_cam, a.world_from_cam, atol=1e-12)
        assert b.camera == a.camera
        assert b.image_file.resolve() == a.image_file.resolve()
        assert b.timestamp == a.timestamp


def test_write_falls_back_to_indices(tmp_path: Path, random_rigid) -> None:
    cam = Camera.pinhole(64, 48, 50, 50, 31.5, 23.5)
    frames = [
        Frame(f"f{i}", cam, random_rigid(), f"{i}.png", None, timestamp=0.5) for i in range(3)
    ]
    write_lamar(Trajectory(tuple(frames)), tmp_path)
    back = read_lamar(tmp_path / "trajectories.txt")
    assert [f.frame_id for f in back] == ["0/cam0", "1/cam0", "2/cam0"]
    assert [f.image_path for f in back] == ["0.png", "1.png", "2.png"]


def test_rig_composition(tmp_path: Path) -> None:
    """world_from_cam = world_from_rig @ rig_from_cam, with numbers checked by hand."""
    rigs = "# rig_id, sensor_id, qw, qx, qy, qz, tx, ty, tz\nrig, cam0, 1, 0, 0, 0, 0.5, 0, 0\n"
    # world_from_rig: 90 deg about z, centre (1, 2, 3)
    c, s = float(np.cos(np.pi / 4)), float(np.sin(np.pi / 4))
    traj_text = (
        f"# t, dev, q, t\n0, rig, {c!r}, 0, 0, {s!r}, 1, 2, 3\n10, cam0, 1, 0, 0, 0, 9, 9, 9\n"
    )
    traj = read_lamar(write_session(tmp_path, rigs__txt=rigs, trajectories__txt=traj_text))
    first = traj.by_id()["0/cam0"]
    assert_allclose(first.center, [1.0, 2.5, 3.0], atol=1e-12)  # (1,2,3) + Rz(90) (0.5,0,0)
    assert_allclose(first.world_from_cam[:3, :3], axis_angle_to_rotmat([0, 0, 1], 90), atol=1e-12)
    assert_allclose(traj.by_id()["10/cam0"].center, [9, 9, 9])  # a direct camera pose still works


def test_images_without_pose_are_skipped_and_sorted(tmp_path: Path, caplog) -> None:
    images = "# h\n20, cam0, c.jpg\n0, cam0, a.jpg\n5, cam0, nopose.jpg\n10, cam0, b.jpg\n"
    traj_text = TRAJ + "20, cam0, 1, 0, 0, 0, 0, 0, 0\n"
    with caplog.at_level(logging.WARNING, logger="pgt_check.io.lamar"):
        traj = read_lamar(write_session(tmp_path, images__txt=images, trajectories__txt=traj_text))
    assert [f.frame_id for f in traj] == ["0/cam0", "10/cam0", "20/cam0"]
    assert any("skipped 1 image" in r.getMessage() for r in caplog.records)


@pytest.mark.parametrize("has_own_sensors", [True, False])
def test_suffix_pairing(tmp_path: Path, has_own_sensors: bool) -> None:
    sfm_sensors = SENSORS.replace("500, 510", "600, 610")
    files = {"trajectories_sfm__txt": TRAJ}
    if has_own_sensors:
        files["sensors_sfm__txt"] = sfm_sensors
    write_session(tmp_path, **files)
    traj = read_lamar(tmp_path / "trajectories_sfm.txt")
    assert traj[0].camera.focal == ((600.0, 610.0) if has_own_sensors else (500.0, 510.0))
    assert traj.metadata["sensors_file"].endswith(
        "sensors_sfm.txt" if has_own_sensors else "sensors.txt"
    )


def test_sensors_override(tmp_path: Path) -> None:
    other = tmp_path / "elsewhere.txt"
    other.write_text(SENSORS.replace("500, 510", "700, 710"))
    traj = read_trajectory(write_session(tmp_path / "s"), sensors=other)
    assert traj[0].camera.focal == (700.0, 710.0)


def test_images_folder_override(tmp_path: Path) -> None:
    traj = read_lamar(write_session(tmp_path / "s"), images=tmp_path)
    assert traj[0].image_file == tmp_path / "images/a.jpg"
    with pytest.raises(InputError, match="not found"):
        read_lamar(tmp_path / "s" / "trajectories.txt", images=tmp_path / "nope")


def test_directory_path_reads_trajectories_txt(tmp_path: Path) -> None:
    write_session(tmp_path)
    assert len(read_trajectory(tmp_path)) == 2


HEAD = "# header\n"
BAD_CASES = {
    # id: (file, content, line, fragment)
    "traj-columns": (
        "trajectories.txt",
        HEAD + "0, cam0, 1, 0, 0, 0, 1, 2\n",
        2,
        "expected 9 fields",
    ),
    "traj-number": (
        "trajectories.txt",
        HEAD + "0, cam0, 1, 0, 0, 0, 1, x, 3\n",
        2,
        "expected a number for ty",
    ),
    "traj-nan": ("trajectories.txt", HEAD + "0, cam0, 1, 0, 0, 0, 1, nan, 3\n", 2, "finite"),
    "traj-quat": (
        "trajectories.txt",
        HEAD + "0, cam0, 1, 0.5, 0, 0, 1, 2, 3\n",
        2,
        "unit quaternion",
    ),
    "traj-timestamp": (
        "trajectories.txt",
        HEAD + "t0, cam0, 1, 0, 0, 0, 1, 2, 3\n",
        2,
        "timestamp",
    ),
    "traj-device": ("trajectories.txt", HEAD + "0, cam7, 1, 0, 0, 0, 1, 2, 3\n", 2, "'cam7'"),
    "traj-duplicate": ("trajectories.txt", TRAJ + "0, cam0, 1, 0, 0, 0, 1, 2, 3\n", 4, "line 2"),
    "traj-empty": ("trajectories.txt", HEAD, 1, "at least one data row"),
    "images-sensor": ("images.txt", HEAD + "0, cam9, a.jpg\n", 2, "'cam9'"),
    "images-columns": ("images.txt", HEAD + "0, cam0\n", 2, "expected 3 fields"),
    "images-duplicate": (
        "images.txt",
        HEAD + "\n0, cam0, a.jpg\n0, cam0, b.jpg\n",
        4,
        "0/cam0 again",
    ),
    "sensors-model": (
        "sensors.txt",
        HEAD + "cam0, x, camera, FISHEYE_X, 640, 480, 1, 2, 3\n",
        2,
        "'FISHEYE_X'",
    ),
    "sensors-params": (
        "sensors.txt",
        HEAD + "cam0, x, camera, PINHOLE, 640, 480, 1, 2, 3\n",
        2,
        "expected 4 parameters",
    ),
    "sensors-size": (
        "sensors.txt",
        HEAD + "cam0, x, camera, PINHOLE, 640.5, 480, 1, 1, 3, 3\n",
        2,
        "integer image size",
    ),
    "sensors-focal": (
        "sensors.txt",
        HEAD + "cam0, x, camera, PINHOLE, 640, 480, -1, 1, 3, 3\n",
        2,
        "focal",
    ),
    "sensors-duplicate": (
        "sensors.txt",
        SENSORS + "cam0, y, camera, PINHOLE, 64, 48, 1, 1, 3, 3\n",
        3,
        "unique sensor ids",
    ),
    "sensors-short": ("sensors.txt", HEAD + "cam0, x\n", 2, "sensor_type"),
    "sensors-not-camera": ("sensors.txt", SENSORS + "imu0, imu, imu\n", None, None),
    "rigs-columns": ("rigs.txt", HEAD + "rig, cam0, 1, 0, 0, 0\n", 2, "expected 9 fields"),
    "rigs-sensor": ("rigs.txt", HEAD + "rig, cam3, 1, 0, 0, 0, 0, 0, 0\n", 2, "'cam3'"),
}


@pytest.mark.parametrize("case", list(BAD_CASES), ids=list(BAD_CASES))
def test_malformed_inputs(tmp_path: Path, case: str, check_error) -> None:
    name, content, line, fragment = BAD_CASES[case]
    path = write_session(tmp_path, **{name.replace(".", "__"): content})
    if fragment is None:  # a valid variation: must read fine
        assert len(read_lamar(path)) == 2
        return
    with pytest.raises(FormatError) as info:
        read_lamar(path)
    check_error(info.value, tmp_path / name, line, fragment)


def test_image_of_non_camera_sensor(tmp_path: Path) -> None:
    path = write_session(
        tmp_path, sensors__txt=SENSORS + "imu0, imu, imu\n", images__txt=HEAD + "0, imu0, a.jpg\n"
    )
    with pytest.raises(FormatError, match=r"images.txt:2: expected a camera .* got 'imu0'"):
        read_lamar(path)


@pytest.mark.parametrize("missing", ["sensors.txt", "images.txt"])
def test_missing_sibling_files(tmp_path: Path, missing: str) -> None:
    path = write_session(tmp_path, **{missing.replace(".", "__"): None})
    with pytest.raises(
        FormatError, match=rf"trajectories.txt: expected an? {missing.split('.')[0]} file"
    ):
        read_lamar(path)


def test_missing_trajectories_file(tmp_path: Path) -> None:
    with pytest.raises(InputError, match="not found"):
        read_lamar(tmp_path / "trajectories.txt")


# --- real data -------------------------------------------------------------------------------


def _first_pose(path: Path) -> np.ndarray:
    row = [r for r in path.read_text().splitlines() if not r.startswith("#")][0]
    return np.array([float(v) for v in row.split(",")[2:]])


@pytest.mark.shared_data
def test_real_7scenes(shared_data: Path) -> None:
    scene = shared_data / "7scenes_redkitchen"
    dslam = read_trajectory(scene / "trajectories.txt")
    sfm = read_trajectory(scene / "trajectories_sfm.txt")
    assert len(dslam) == len(sfm) == 100
    assert dslam[0].camera == Camera.pinhole(640, 480, 525.0, 525.0, 319.5, 239.5)
    assert sfm[0].camera == Camera.pinhole(
        640, 480, 525.505, 525.505, 319.5, 239.5
    )  # sensors_sfm.txt
    assert sfm.metadata["sensors_file"].endswith("sensors_sfm.txt")
    assert [f.frame_id for f in dslam][:3] == ["0/cam0", "10/cam0", "20/cam0"]
    assert all(f.image_file.is_file() for f in dslam)
    assert dslam[0].image_path == "images/frame-000000.color.jpg"
    qt = _first_pose(scene / "trajectories.txt")
    assert_allclose(dslam[0].center, qt[4:])
    # the two pose sources differ by centimetres (README: median 7.4 cm), not metres
    dt = [np.linalg.norm(a.center - b.center) for a, b in zip(dslam, sfm, strict=True)]
    assert 0.02 < np.median(dt) < 0.2


@pytest.mark.shared_data
def test_real_sceaux_colmap_pairing(shared_data: Path) -> None:
    scene = shared_data / "sceaux_castle"
    mvs = read_trajectory(scene / "trajectories.txt")
    colmap = read_trajectory(scene / "trajectories_colmap.txt")
    assert len(mvs) == len(colmap) == 10
    assert colmap[0].camera == Camera.pinhole(1416, 1064, 1485.855, 1485.855, 707.5, 531.5)
    assert mvs[0].camera.focal == (1492.664171, 1492.664171)
    assert_allclose(colmap[0].center, _first_pose(scene / "trajectories_colmap.txt")[4:])


@settings(
    max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(
    q=st.lists(st.floats(-1, 1), min_size=4, max_size=4).filter(lambda v: np.linalg.norm(v) > 0.1),
    t=st.lists(st.floats(-1e6, 1e6), min_size=3, max_size=3),
    cx=st.floats(0, 639),
)
def test_round_trip_property(tmp_path_factory, q, t, cx) -> None:
    """Any rotation, georeferenced-size translations and any principal point survive a round trip."""
    directory = tmp_path_factory.mktemp("rt")
    q = np.asarray(q) / np.linalg.norm(q)
    pose = make_rigid(quat_to_rotmat(q), t)
    cam = Camera.pinhole(640, 480, 500.0, 500.0, cx, 240.0)
    write_lamar(Trajectory((Frame("x", cam, pose, "a.png", None, timestamp=7.0),)), directory)
    back = read_lamar(directory / "trajectories.txt")[0]
    assert_allclose(back.world_from_cam[:3, :3], pose[:3, :3], atol=1e-12)
    assert_allclose(back.world_from_cam[:3, 3], pose[:3, 3], rtol=0, atol=1e-9)
    assert_allclose(back.camera.params, cam.params, rtol=0, atol=1e-12)  # cx +0.5 -0.5: 1 ulp
    assert back.frame_id == "7/cam0"


def test_images_under_raw_data_are_found(tmp_path: Path) -> None:
    """A LaMAR session keeps images under raw_data/, with paths relative to it."""
    path = write_session(tmp_path / "s")
    (tmp_path / "s" / "raw_data" / "images").mkdir(parents=True)
    (tmp_path / "s" / "raw_data" / "images" / "a.jpg").write_bytes(b"")
    traj = read_trajectory(path)
    assert traj[0].image_file == tmp_path / "s" / "raw_data" / "images" / "a.jpg"
    assert traj.metadata["images_dir"] == str(tmp_path / "s" / "raw_data")
    # paths that resolve beside images.txt (and not under raw_data/) keep that root
    (tmp_path / "s" / "images").mkdir()
    (tmp_path / "s" / "images" / "a.jpg").write_bytes(b"")
    (tmp_path / "s" / "raw_data" / "images" / "a.jpg").unlink()
    assert read_lamar(path)[0].image_file == tmp_path / "s" / "images" / "a.jpg"
    # an explicit folder wins
    assert read_lamar(path, images=tmp_path)[0].image_file == tmp_path / "images" / "a.jpg"
