"""Pose writers: a trajectory back into the format it was read from.

``write_trajectory_file(trajectory, path)`` picks the writer from ``trajectory.format``: LaMAR
-> a LaMAR trajectories file, COLMAP -> ``images.txt``, TUM -> a TUM file; every other format ->
a LaMAR trajectories file. Poses are written as each format stores them (LaMAR and TUM:
world_from_cam; COLMAP: cam_from_world). The files read back with ``read_trajectory`` to the
same poses (to float64 ``repr`` precision).
"""

from __future__ import annotations

import logging
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from pgt_check.common.files import atomic_write_text
from pgt_check.geometry.transforms import invert_rigid, rotmat_to_quat
from pgt_check.types import Camera, Trajectory

logger = logging.getLogger(__name__)

__all__ = [
    "lamar_trajectory_text",
    "colmap_images_text",
    "tum_text",
    "write_trajectory_file",
]


def _fmt(value: float) -> str:
    return repr(float(value))


def _lamar_key(frame_id: str, index: int, camera_id: str) -> tuple[str, str]:
    """(timestamp, device id) of a frame: LaMAR ids are ``"{timestamp}/{sensor}"``."""
    stamp, sep, sensor = frame_id.partition("/")
    if sep and stamp and sensor and "," not in frame_id:
        return stamp, sensor
    return str(index), camera_id


def lamar_trajectory_text(trajectory: Trajectory) -> str:
    """A LaMAR ``trajectories.txt``: ``timestamp, device_id, qw, qx, qy, qz, tx, ty, tz``.

    LaMAR frame ids (``timestamp/sensor``) keep their timestamp and sensor (a pose given for a
    rig is written for the camera); other frames get their index and ``cam0, cam1, ...`` (one
    per distinct camera, the ids ``pgt_check.io.write_lamar`` gives them).
    """
    camera_ids: dict[Camera, str] = {}
    rows = ["# timestamp, device_id, qw, qx, qy, qz, tx, ty, tz"]
    for i, frame in enumerate(trajectory):
        cam_id = camera_ids.setdefault(frame.camera, f"cam{len(camera_ids)}")
        stamp, device = (
            _lamar_key(frame.frame_id, i, cam_id)
            if trajectory.format == "lamar"
            else (str(i), cam_id)
        )
        q = rotmat_to_quat(frame.world_from_cam[:3, :3])
        t = frame.world_from_cam[:3, 3]
        rows.append(f"{stamp}, {device}, " + ", ".join(_fmt(v) for v in (*q, *t)))
    return "\n".join(rows) + "\n"


def colmap_images_text(
    trajectory: Trajectory,
    image_ids: Mapping[str, int] | None = None,
    camera_ids: Mapping[str, int] | None = None,
) -> str:
    """A COLMAP ``images.txt`` (no 2D points: every second line is empty).

    ``image_ids`` / ``camera_ids``: by image name (frame id), e.g. those of the model read;
    missing ones are numbered (images 1, 2, ... in trajectory order; cameras by distinct Camera).
    """
    image_ids = dict(image_ids or {})
    camera_ids = dict(camera_ids or {})
    own_cam: dict[Camera, int] = {}
    rows = [
        "# Image list with two lines of data per image:",
        "#   IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME",
        "#   POINTS2D[] as (X, Y, POINT3D_ID)",
        f"# Number of images: {len(trajectory)}",
    ]
    used = set(image_ids.values())
    next_id = 1
    for frame in trajectory:
        name = frame.image_path or frame.frame_id
        if name in image_ids:
            iid = image_ids[name]
        else:
            while next_id in used:
                next_id += 1
            iid, next_id = next_id, next_id + 1
            used.add(iid)
        cid = camera_ids.get(name) or own_cam.setdefault(frame.camera, len(own_cam) + 1)
        cfw = invert_rigid(frame.world_from_cam)
        q = rotmat_to_quat(cfw[:3, :3])
        vals = " ".join(_fmt(v) for v in (*q, *cfw[:3, 3]))
        rows.append(f"{iid} {vals} {cid} {name}")
        rows.append("")
    return "\n".join(rows) + "\n"


def tum_text(trajectory: Trajectory) -> str:
    """A TUM trajectory: ``timestamp tx ty tz qx qy qz qw`` (world_from_cam).

    The timestamp is the frame id (TUM ids are the timestamps as written), else the frame's
    timestamp, else its index.
    """
    rows = ["# timestamp tx ty tz qx qy qz qw"]
    for i, frame in enumerate(trajectory):
        stamp = frame.frame_id if trajectory.format == "tum" else (
            _fmt(frame.timestamp) if frame.timestamp is not None else str(i)
        )
        qw, qx, qy, qz = rotmat_to_quat(frame.world_from_cam[:3, :3])
        t = frame.world_from_cam[:3, 3]
        rows.append(f"{stamp} " + " ".join(_fmt(v) for v in (*t, qx, qy, qz, qw)))
    return "\n".join(rows) + "\n"


#: the file format written for each input format (others: LaMAR)
OUTPUT_FORMAT = {"lamar": "lamar", "colmap": "colmap", "tum": "tum"}


def _colmap_ids(source: str) -> tuple[dict[str, int], dict[str, int]]:
    """(image id, camera id) by image name of the COLMAP model at ``source``; empty if unreadable."""
    try:
        import pycolmap

        rec = pycolmap.Reconstruction(str(source))
    except Exception as err:  # the ids are a courtesy: numbering them is still a valid file
        logger.debug("cannot reread %s for image ids: %s", source, err)
        return {}, {}
    images = rec.images.values()
    return {im.name: int(im.image_id) for im in images}, {
        im.name: int(im.camera_id) for im in images
    }


def write_trajectory_file(trajectory: Trajectory, path: str | Path) -> str:
    """Write ``trajectory`` to ``path`` in its input's own format; returns the format written
    ("lamar", "colmap" (an images.txt) or "tum")."""
    fmt = OUTPUT_FORMAT.get(trajectory.format, "lamar")
    if fmt == "colmap":
        image_ids, camera_ids = _colmap_ids(trajectory.source) if trajectory.source else ({}, {})
        text = colmap_images_text(trajectory, image_ids, camera_ids)
    elif fmt == "tum":
        text = tum_text(trajectory)
    else:
        text = lamar_trajectory_text(trajectory)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_text(path, text)
    return fmt


def poses_equal(a: Trajectory, b: Trajectory, atol: float = 1e-9) -> bool:
    """True when both trajectories hold the same frame ids with the same poses."""
    pa, pb = a.by_id(), b.by_id()
    return pa.keys() == pb.keys() and all(
        np.allclose(pa[k].world_from_cam, pb[k].world_from_cam, atol=atol) for k in pa
    )
