"""LaMAR "Capture" text format: sensors, images, trajectories and (optional) rigs files.

What the files store:

* ``trajectories*.txt``: ``timestamp, device_id, qw, qx, qy, qz, tx, ty, tz`` = **world_from_device**
  (camera-to-world, ``X_world = R(q) X_device + t``), OpenCV camera axes, Hamilton quaternion with
  the scalar first. ``device_id`` is a camera sensor or a rig.
* ``rigs*.txt``: ``rig_id, sensor_id, qw, qx, qy, qz, tx, ty, tz`` = **rig_from_sensor**, so
  ``world_from_cam = world_from_rig @ rig_from_cam``.
* ``sensors*.txt``: ``sensor_id, name, sensor_type, [params]``; camera rows are
  ``cam0, name, camera, MODEL, width, height, params...`` with COLMAP parameters in the COLMAP pixel
  convention (top-left pixel centre at (0.5, 0.5)); the reader subtracts 0.5 from cx, cy.
* ``images*.txt``: ``timestamp, sensor_id, image_path``, paths relative to the file's folder.

Lines starting with ``#`` are comments; whitespace around commas is ignored.
"""

from __future__ import annotations

import logging
import re
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pgt_check.errors import FormatError, InputError
from pgt_check.io._text import (
    QuaternionCounter,
    UniqueKeys,
    check_frame_id,
    data_lines,
    parse_float,
    parse_timestamp,
    split_row,
)
from pgt_check.io.camera import camera_from_colmap
from pgt_check.types import Camera, Frame, Trajectory

logger = logging.getLogger(__name__)

POSE_LAYOUT = "qw, qx, qy, qz, tx, ty, tz"


@dataclass(frozen=True)
class LamarFiles:
    """The files of one LaMAR session, paired by suffix (``trajectories_sfm.txt`` -> ``_sfm``)."""

    trajectories: Path
    sensors: Path
    images: Path
    rigs: Path | None
    suffix: str


def _sibling(directory: Path, kind: str, suffix: str) -> Path | None:
    """``{kind}{suffix}.txt`` if it exists, else ``{kind}.txt`` if it exists, else None."""
    for name in (f"{kind}{suffix}.txt", f"{kind}.txt"):
        candidate = directory / name
        if candidate.is_file():
            return candidate
    return None


def find_lamar_files(
    path: str | Path, *, sensors: str | Path | None = None, images: str | Path | None = None
) -> LamarFiles:
    """Locate the files that go with a trajectories file (or a session directory).

    ``trajectories{suffix}.txt`` pairs with ``sensors{suffix}.txt`` if it exists, else
    ``sensors.txt``; the same for images and rigs. ``sensors`` / ``images`` (a list file)
    override the pairing.
    """
    path = Path(path)
    if path.is_dir():
        path = path / "trajectories.txt"
    if not path.is_file():
        raise InputError(f"{path}: trajectories file not found")
    match = re.fullmatch(r"trajectories(.*)", path.stem)
    suffix = match.group(1) if match else ""
    directory = path.parent
    tried = f"sensors{suffix}.txt" + (" or sensors.txt" if suffix else "")
    if sensors is not None:
        sensors_file = Path(sensors)
        if not sensors_file.is_file():
            raise InputError(f"{sensors_file}: sensors file not found")
    else:
        found = _sibling(directory, "sensors", suffix)
        if found is None:
            raise FormatError(path, None, f"expected a sensors file ({tried}) beside it; got none")
        sensors_file = found
    if images is not None and Path(images).is_file():
        images_file = Path(images)
    else:
        found = _sibling(directory, "images", suffix)
        if found is None:
            tried = f"images{suffix}.txt" + (" or images.txt" if suffix else "")
            raise FormatError(path, None, f"expected an images file ({tried}) beside it; got none")
        images_file = found
    return LamarFiles(path, sensors_file, images_file, _sibling(directory, "rigs", suffix), suffix)


def read_sensors(path: Path) -> tuple[dict[str, Camera], set[str]]:
    """Cameras by sensor id, and the ids of every sensor (cameras or not)."""
    cameras: dict[str, Camera] = {}
    seen = UniqueKeys(path, "unique sensor ids")
    for line, text in data_lines(path):
        fields = [f.strip() for f in text.split(",")]
        if len(fields) < 3:
            raise FormatError(
                path,
                line,
                f"expected sensor_id, name, sensor_type[, params]; got {len(fields)} fields",
            )
        sensor_id, _name, sensor_type = fields[:3]
        if not sensor_id:
            raise FormatError(path, line, "expected a sensor id; got an empty field")
        check_frame_id(path, line, sensor_id, what="sensor id")
        seen.add(sensor_id, repr(sensor_id), line)
        if sensor_type != "camera":
            continue
        if len(fields) < 6:
            raise FormatError(
                path,
                line,
                f"expected a camera row (id, name, camera, MODEL, width, height, params...); got {len(fields)} fields",
            )
        width = parse_float(path, line, fields[4], "width")
        height = parse_float(path, line, fields[5], "height")
        params = [parse_float(path, line, p, "camera parameter") for p in fields[6:]]
        cameras[sensor_id] = camera_from_colmap(path, line, fields[3], width, height, params)
    return cameras, {str(k) for k in seen.first}


def read_rigs(path: Path, sensor_ids: set[str]) -> dict[tuple[str, str], np.ndarray]:
    """rig_from_sensor (4x4) by (rig_id, sensor_id)."""
    quats = QuaternionCounter(path)
    rigs: dict[tuple[str, str], np.ndarray] = {}
    seen = UniqueKeys(path, "unique (rig, sensor) pairs")
    for line, text in data_lines(path, allow_empty=True):
        fields = split_row(
            path, line, text, count=9, sep=",", layout=f"rig_id, sensor_id, {POSE_LAYOUT}"
        )
        rig_id, sensor_id = fields[:2]
        if sensor_id not in sensor_ids:
            raise FormatError(
                path, line, f"expected a sensor id from the sensors file; got {sensor_id!r}"
            )
        seen.add((rig_id, sensor_id), f"{rig_id}, {sensor_id}", line)
        rigs[(rig_id, sensor_id)] = _parse_pose(path, line, fields[2:], quats)
    quats.report()
    return rigs


def _parse_pose(path: Path, line: int, fields: list[str], quats) -> np.ndarray:
    """The 7 pose columns ``qw, qx, qy, qz, tx, ty, tz`` of one row -> (4, 4) rigid transform."""
    values = [
        parse_float(path, line, v, n)
        for v, n in zip(fields, POSE_LAYOUT.split(", "), strict=True)
    ]
    return quats.rigid(line, values[:4], values[4:])


def read_poses(path: Path, device_ids: set[str]) -> dict[tuple[float, str], np.ndarray]:
    """world_from_device (4x4) by (timestamp, device_id)."""
    quats = QuaternionCounter(path)
    poses: dict[tuple[float, str], np.ndarray] = {}
    seen = UniqueKeys(path, "one pose per (timestamp, device)")
    for line, text in data_lines(path):
        fields = split_row(
            path, line, text, count=9, sep=",", layout=f"timestamp, device_id, {POSE_LAYOUT}"
        )
        timestamp = parse_timestamp(path, line, fields[0])
        device_id = fields[1]
        if device_id not in device_ids:
            raise FormatError(
                path,
                line,
                f"expected a device id from the sensors or rigs file ({', '.join(sorted(device_ids))}); got {device_id!r}",
            )
        seen.add((timestamp, device_id), f"{fields[0]}, {device_id}", line)
        poses[(timestamp, device_id)] = _parse_pose(path, line, fields[2:], quats)
    quats.report()
    return poses


def _first_image_path(rows: list[tuple[int, str]]) -> str | None:
    fields = rows[0][1].split(",") if rows else []
    return fields[2].strip() if len(fields) == 3 else None


def default_image_root(images_file: Path, first_image: str | None) -> Path:
    """Where the paths of a LaMAR images file are resolved when no folder is given.

    A LaMAR session keeps its images under ``raw_data/`` beside ``images.txt``, with paths
    relative to it; other exports write paths relative to the images file's folder. ``raw_data/``
    is taken when it exists, unless the first listed image exists beside the file and not under
    ``raw_data/``.
    """
    base = images_file.parent
    raw = base / "raw_data"
    if not raw.is_dir():
        return base
    if first_image and (base / first_image).exists() and not (raw / first_image).exists():
        return base
    return raw


def read_lamar(
    path: str | Path, *, sensors: str | Path | None = None, images: str | Path | None = None
) -> Trajectory:
    """Read a LaMAR trajectories file with its sensors, images and rigs files.

    ``images`` may be a list file (replaces ``images*.txt``) or a folder (the root that image
    paths are resolved against; default: ``default_image_root``, the images file's folder or the
    session's ``raw_data/``). frame_id is
    ``"{timestamp}/{sensor_id}"`` as written in the images file. Images without a pose are
    skipped (one WARNING with the count); a camera or rig pose without an image stays a frame
    without one (``image_file`` None: UNVERIFIABLE image_missing, counted by the gate; one
    WARNING with the count). Frames are sorted by timestamp, then sensor id.
    """
    if images is not None and not Path(images).exists():
        raise InputError(f"{images}: images folder or list file not found")
    files = find_lamar_files(path, sensors=sensors, images=images)
    cameras, sensor_ids = read_sensors(files.sensors)
    rigs, poses = _rigs_and_poses(files, sensor_ids)
    image_rows = data_lines(files.images)
    if images is not None and Path(images).is_dir():
        root = Path(images)
    else:
        root = default_image_root(files.images, _first_image_path(image_rows))
    frames = _imaged_frames(files, image_rows, root, cameras, sensor_ids, rigs, poses)
    frames += _frames_without_image(files, poses, rigs, cameras, frames)
    frames.sort(key=lambda item: (item[0], item[1]))
    logger.info(
        "read %d frames from %s (sensors: %s)", len(frames), files.trajectories, files.sensors.name
    )
    return Trajectory(
        tuple(f for _, _, f in frames),
        source=str(files.trajectories),
        format="lamar",
        metadata=_metadata(files, root),
    )


def _image_row(
    files: LamarFiles, line: int, text: str, cameras: dict[str, Camera], sensor_ids: set[str]
) -> tuple[str, str, str, float]:
    """``(timestamp text, sensor id, image path, timestamp)`` of one images-file row, checked."""
    fields = split_row(
        files.images, line, text, count=3, sep=",", layout="timestamp, sensor_id, image_path"
    )
    stamp_text, sensor_id, image_path = fields
    timestamp = parse_timestamp(files.images, line, stamp_text)
    if sensor_id not in cameras:
        known = ", ".join(sorted(cameras)) or "none"
        what = "a camera" if sensor_id in sensor_ids else "a sensor id"
        raise FormatError(
            files.images,
            line,
            f"expected {what} from {files.sensors.name} ({known}); got {sensor_id!r}",
        )
    if not image_path:
        raise FormatError(files.images, line, "expected an image path; got an empty field")
    return stamp_text, sensor_id, image_path, timestamp


def _imaged_frames(
    files: LamarFiles,
    image_rows: list[tuple[int, str]],
    root: Path,
    cameras: dict[str, Camera],
    sensor_ids: set[str],
    rigs: dict,
    poses: dict,
) -> list[tuple[float, str, Frame]]:
    """``(timestamp, sensor id, Frame)`` of every image row with a pose, in file order; the
    rows without one are skipped with one WARNING."""
    rigs_of: dict[str, list[str]] = {}
    for rig, sensor in rigs:
        rigs_of.setdefault(sensor, []).append(rig)
    frames: list[tuple[float, str, Frame]] = []
    seen = UniqueKeys(files.images, "one image per (timestamp, sensor)")
    unposed: list[str] = []
    for line, text in image_rows:
        stamp_text, sensor_id, image_path, timestamp = _image_row(
            files, line, text, cameras, sensor_ids
        )
        frame_id = f"{stamp_text}/{sensor_id}"
        check_frame_id(files.images, line, frame_id)
        seen.add(frame_id, frame_id, line)
        world_from_cam = _camera_pose(poses, rigs, rigs_of.get(sensor_id, ()), timestamp, sensor_id)
        if world_from_cam is None:
            unposed.append(frame_id)
            continue
        frame = Frame(
            frame_id=frame_id,
            camera=cameras[sensor_id],
            world_from_cam=world_from_cam,
            image_path=image_path,
            image_file=root / image_path,
            timestamp=timestamp,
        )
        frames.append((timestamp, sensor_id, frame))
    if unposed:
        logger.warning(
            "%s: skipped %d image(s) with no pose in %s (first: %s)",
            files.images,
            len(unposed),
            files.trajectories.name,
            unposed[0],
        )
    return frames


def _frames_without_image(
    files: LamarFiles,
    poses: dict,
    rigs: dict,
    cameras: dict[str, Camera],
    frames: list[tuple[float, str, Frame]],
) -> list[tuple[float, str, Frame]]:
    """``(timestamp, camera id, Frame)`` without an image for every pose no image row uses
    (see ``_poses_without_image``), with one WARNING if there are any."""
    imaged = {(stamp, sensor) for stamp, sensor, _ in frames}
    no_image = _poses_without_image(poses, rigs, cameras, imaged)
    out: list[tuple[float, str, Frame]] = []
    for (stamp, sensor), world_from_cam in no_image.items():
        # kept: checked as UNVERIFIABLE image_missing (and counted by the gate), never dropped
        frame_id = f"{_stamp_text(stamp)}/{sensor}"
        out.append(
            (stamp, sensor, Frame(frame_id, cameras[sensor], world_from_cam, "", None, stamp))
        )
    if no_image:
        logger.warning(
            "%s: %d camera or rig pose(s) have no image in %s (first: %s); they are "
            "UNVERIFIABLE image_missing",
            files.trajectories,
            len(no_image),
            files.images.name,
            "/".join(map(str, next(iter(no_image)))),
        )
    return out


def _rigs_and_poses(files: LamarFiles, sensor_ids: set[str]) -> tuple[dict, dict]:
    """The rigs file's ``{(rig, sensor): rig_from_sensor}`` (empty without one) and the poses
    of the sensors and rigs; rig ids must differ from sensor ids."""
    rigs = read_rigs(files.rigs, sensor_ids) if files.rigs is not None else {}
    rig_ids = {rig for rig, _ in rigs}
    clash = rig_ids & sensor_ids
    if clash and files.rigs is not None:
        raise FormatError(
            files.rigs,
            None,
            f"expected rig ids distinct from sensor ids; got {', '.join(sorted(clash))}",
        )
    return rigs, read_poses(files.trajectories, sensor_ids | rig_ids)


def _camera_pose(
    poses: dict, rigs: dict, rigs_of_sensor: Sequence[str], timestamp: float, sensor_id: str
) -> np.ndarray | None:
    """world_from_cam of a sensor at a timestamp: its own pose, else through the first rig
    with a pose at that timestamp; None if neither exists."""
    world_from_cam = poses.get((timestamp, sensor_id))
    if world_from_cam is None:
        for rig in rigs_of_sensor:
            world_from_rig = poses.get((timestamp, rig))
            if world_from_rig is not None:
                return world_from_rig @ rigs[(rig, sensor_id)]
    return world_from_cam


def _poses_without_image(
    poses: dict, rigs: dict, cameras: dict[str, Camera], imaged: set[tuple[float, str]]
) -> dict[tuple[float, str], np.ndarray]:
    """(timestamp, camera id) -> world_from_cam of every pose of the trajectories file that no
    image row uses: a camera's own pose without an image at its timestamp, and a rig pose none
    of whose cameras has an image then (its first camera, by id, stands for it). Poses of
    sensors that are no camera (depth, lidar) are not poses of images and are left out."""
    cameras_of_rig: dict[str, list[str]] = {}
    for rig, sensor in sorted(rigs):
        if sensor in cameras:
            cameras_of_rig.setdefault(rig, []).append(sensor)
    out: dict[tuple[float, str], np.ndarray] = {}
    for (stamp, device), world_from_device in poses.items():
        if device in cameras:
            if (stamp, device) not in imaged:
                out.setdefault((stamp, device), world_from_device)
        elif device in cameras_of_rig:
            cams = cameras_of_rig[device]
            if not any((stamp, c) in imaged for c in cams):
                out.setdefault((stamp, cams[0]), world_from_device @ rigs[(device, cams[0])])
    return out


def _stamp_text(stamp: float) -> str:
    """A timestamp as a frame id part: an integer without a decimal point."""
    return str(int(stamp)) if float(stamp).is_integer() else repr(float(stamp))


def _metadata(files: LamarFiles, root: Path) -> dict[str, str]:
    metadata = {
        "trajectories_file": str(files.trajectories),
        "sensors_file": str(files.sensors),
        "images_file": str(files.images),
        "images_dir": str(root),
    }
    if files.rigs is not None:
        metadata["rigs_file"] = str(files.rigs)
    return metadata
