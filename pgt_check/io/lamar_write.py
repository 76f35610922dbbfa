"""Writing the LaMAR "Capture" text format (``write_lamar``): sensors, images and trajectories
files that ``io.lamar.read_lamar`` reads back (the conventions are in ``io.lamar``)."""

from __future__ import annotations

import logging
import os
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from pgt_check.common.files import atomic_write_text
from pgt_check.errors import InputError
from pgt_check.geometry.transforms import rotmat_to_quat
from pgt_check.io.camera import opencv_to_colmap_params
from pgt_check.io.lamar import POSE_LAYOUT
from pgt_check.types import Camera, Frame, Trajectory

logger = logging.getLogger(__name__)


def _fmt(value: float) -> str:
    return repr(float(value))


def write_lamar(
    trajectory: Trajectory,
    directory: str | Path,
    suffix: str = "",
    rigs: Mapping[Camera, tuple[Camera, np.ndarray]] | None = None,
) -> dict[str, Path]:
    """Write ``sensors{suffix}.txt``, ``images{suffix}.txt``, ``trajectories{suffix}.txt``
    (and ``rigs{suffix}.txt`` with ``rigs``).

    Cameras get ids ``cam0, cam1, ...`` (one per distinct Camera), written in COLMAP pixel
    convention (0.5 added to cx, cy). Timestamps are the frames' timestamps when they are all
    integers and unique per camera, else the frame indices. Image paths are written relative to
    ``directory`` when the frame has a resolved ``image_file``, else ``image_path`` verbatim.
    Poses are world_from_cam, one row per frame. ``rigs``: for the frames of a camera listed
    there, ``(camera written instead, (4, 4) rig_from_cam)``: the frame's pose is written as the
    pose of rig ``rig_<cam id>`` (world_from_rig) and the rigs file places the camera in it, so
    ``read_lamar`` gives world_from_rig @ rig_from_cam. Returns the written paths by kind.
    """
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    rigs = dict(rigs or {})
    camera_ids: dict[Camera, str] = {}
    for frame in trajectory:
        camera_ids.setdefault(frame.camera, f"cam{len(camera_ids)}")
    stamp_text = _stamp_texts(trajectory, camera_ids, directory)
    sensors_rows = _sensors_rows([(rigs[c][0] if c in rigs else c, i) for c, i in camera_ids.items()])
    images_rows = ["# timestamp, sensor_id, image_path"]
    traj_rows = [f"# timestamp, device_id, {POSE_LAYOUT}"]
    for stamp, frame in zip(stamp_text, trajectory, strict=True):
        cam_id = camera_ids[frame.camera]
        device = f"rig_{cam_id}" if frame.camera in rigs else cam_id
        image = _image_text(frame, directory)
        if image is not None:  # a pose without an image stays a frame without one
            images_rows.append(f"{stamp}, {cam_id}, {image}")
        traj_rows.append(f"{stamp}, {device}, {_pose_text(frame.world_from_cam)}")
    out = {
        "sensors": directory / f"sensors{suffix}.txt",
        "images": directory / f"images{suffix}.txt",
        "trajectories": directory / f"trajectories{suffix}.txt",
    }
    texts = [("sensors", sensors_rows), ("images", images_rows), ("trajectories", traj_rows)]
    if rigs:
        out["rigs"] = directory / f"rigs{suffix}.txt"
        texts.append(("rigs", [f"# rig_id, sensor_id, {POSE_LAYOUT}"] + [
            f"rig_{camera_ids[c]}, {camera_ids[c]}, {_pose_text(np.asarray(r, np.float64))}"
            for c, (_, r) in rigs.items() if c in camera_ids
        ]))
    for kind, rows in texts:
        atomic_write_text(out[kind], "\n".join(rows) + "\n")  # a link replaced, not followed
    return out


def _pose_text(pose: np.ndarray) -> str:
    """``qw, qx, qy, qz, tx, ty, tz`` of a (4, 4) rigid transform."""
    q = rotmat_to_quat(pose[:3, :3])
    return ", ".join(_fmt(v) for v in (*q, *pose[:3, 3]))


def _stamp_texts(
    trajectory: Trajectory, camera_ids: dict[Camera, str], directory: Path
) -> list[str]:
    """The timestamp column of each frame: its timestamp if all are integers and unique per
    camera, else the frame indices (logged at INFO)."""
    stamps = [f.timestamp for f in trajectory]
    keys = {(s, camera_ids[f.camera]) for s, f in zip(stamps, trajectory, strict=True)}
    if any(s is None or float(s) != int(s) for s in stamps) or len(keys) != len(trajectory):
        if trajectory.frames:
            logger.info(
                "%s: timestamps are missing, non-integer or repeated; writing frame indices",
                directory,
            )
        stamps = list(range(len(trajectory)))
    return [str(int(s)) for s in stamps]


def _sensors_rows(camera_ids: list[tuple[Camera, str]]) -> list[str]:
    """The lines of the sensors file (header first), one camera row per (camera, id)."""
    sensors_rows = ["# sensor_id, name, sensor_type, [sensor_params]+"]
    for camera, cam_id in camera_ids:
        values = ", ".join(_fmt(p) for p in opencv_to_colmap_params(camera.model, camera.params))
        sensors_rows.append(
            f"{cam_id}, {cam_id}, camera, {camera.model}, {camera.width}, {camera.height}, {values}"
        )
    return sensors_rows


def _image_text(frame: Frame, directory: Path) -> str | None:
    """A frame's image path as written in the images file: relative to ``directory`` when the
    frame has an ``image_file``, else its ``image_path`` (None when it has neither); raises
    InputError if unwritable."""
    if frame.image_file is not None:
        image = Path(
            os.path.relpath(Path(frame.image_file).absolute(), directory.absolute())
        ).as_posix()
    else:
        image = frame.image_path
    if image is None:
        return None
    if "," in image or not image:
        raise InputError(
            f"frame {frame.frame_id}: image path {image!r} cannot be written to a LaMAR file"
        )
    return image
