"""The run-level calibration estimate written exactly, as a LaMAR session with a rig
(``calibrated/``): what ``calibrated_sensors.txt`` cannot hold.

The calibration check estimates, per camera, ``true_cam_from_checked_cam`` (a rotation ``R``
and, with ``--calibration-translation``, a translation ``t``) and a focal scale ``s``
(``verdict.shared_results.CalibrationCheck``). ``calibrated_sensors.txt`` approximates the
rotation by a principal-point shift (its roll, keystone and translation are lost; it says how
many px that leaves). The exact form of "the photo camera sits at this rotation and offset from
the sensor whose poses are given" is a rig: LaMAR's ``rigs.txt`` holds ``rig_from_sensor``,
and a trajectory that poses the rig gives ``world_from_cam = world_from_rig @ rig_from_cam``.

Written into ``out/calibrated/`` when a camera's calibration is significant (failed or a
finding): ``trajectories.txt`` (the given poses, now the rig's: ``rig_<camera>``),
``rigs.txt`` (``rig_from_cam`` = ``checked_cam_from_true_cam`` = (R, t) inverted),
``sensors.txt`` (focal lengths x ``s``, principal point and distortion as given) and
``images.txt`` (paths relative to the folder). ``pgt-check out/calibrated/trajectories.txt
--mesh MESH`` re-checks the run with the estimate applied; cameras without a significant
estimate are written unchanged. A folder of an earlier run is removed when nothing is
significant.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from pgt_check.geometry.transforms import invert_rigid
from pgt_check.measure.record import camera_key
from pgt_check.types import CAMERA_MODELS, Camera, Trajectory
from pgt_check.verdict.shared import SharedChecks
from pgt_check.verdict.shared_results import CalibrationCheck
from pgt_check.verdict.status import FAILED, FINDING

logger = logging.getLogger(__name__)

CALIBRATED_DIR = "calibrated"
#: the files ``write_calibrated_rig`` writes (and removes when they would be stale)
CALIBRATED_FILES = ("sensors.txt", "images.txt", "trajectories.txt", "rigs.txt")


def with_focal_scale(
    camera: Camera, scale: float, principal_point: tuple[float, float] | None = None
) -> Camera:
    """``camera`` with its focal length(s) multiplied by ``scale`` and, if given, its principal
    point replaced (OpenCV pixels); distortion and size unchanged."""
    names = CAMERA_MODELS[camera.model]
    params = dict(zip(names, camera.params, strict=True))
    for key in ("f", "fx", "fy"):
        if key in params:
            params[key] *= scale
    if principal_point is not None:
        params["cx"], params["cy"] = principal_point
    return Camera(camera.model, camera.width, camera.height, tuple(params[n] for n in names))


def rig_from_cam(entry: CalibrationCheck) -> np.ndarray:
    """(4, 4) ``checked_cam_from_true_cam``: where the photo camera sits in the posed sensor's
    frame (the inverse of the estimate's ``true_cam_from_checked_cam``)."""
    if entry.rotation is None:
        raise ValueError("the calibration entry has no rotation estimate")
    m = np.eye(4)
    m[:3, :3] = np.asarray(entry.rotation, np.float64)
    if entry.translation is not None:
        m[:3, 3] = np.asarray(entry.translation, np.float64).reshape(3)
    return invert_rigid(m)


def significant_calibrations(shared: SharedChecks | None) -> dict[str, CalibrationCheck]:
    """Camera key -> its calibration check, for the cameras whose estimate is significant and
    complete (rotation and focal scale)."""
    if shared is None:
        return {}
    return {
        k: c for k, c in shared.calibration.items()
        if c.status in (FAILED, FINDING) and c.rotation is not None and c.focal_scale is not None
    }  # fmt: skip


def write_calibrated_rig(
    trajectory: Trajectory, shared: SharedChecks | None, out: str | Path
) -> CalibratedRig | None:
    """Write ``out/calibrated/`` (module docstring) and return what it holds; None (and an
    earlier run's files removed) when no camera's calibration is significant."""
    from pgt_check.io.lamar_write import write_lamar

    folder = Path(out) / CALIBRATED_DIR
    cals = significant_calibrations(shared)
    cams = {f.camera for f in trajectory.frames}
    rigs: dict[Camera, tuple[Camera, np.ndarray]] = {}
    for cam in cams:
        entry = cals.get(camera_key(cam))
        if entry is not None:
            rigs[cam] = (with_focal_scale(cam, float(entry.focal_scale or 1.0)),
                         rig_from_cam(entry))
    if not rigs:
        for name in CALIBRATED_FILES:
            (folder / name).unlink(missing_ok=True)
        if folder.is_dir() and not any(folder.iterdir()):
            folder.rmdir()
        return None
    files = write_lamar(trajectory, folder, rigs=rigs)
    logger.info("wrote %s (the calibration estimate as a rig, %d camera(s))", folder, len(rigs))
    return CalibratedRig(
        trajectory_file=f"{CALIBRATED_DIR}/{files['trajectories'].name}",
        cameras={camera_key(c): RigCamera.of(e, r) for c, (e, r) in rigs.items()},
    )


@dataclass(frozen=True)
class RigCamera:
    """One camera of the rig session: the camera written (focal lengths scaled) and where it
    sits in the posed sensor (``rig_from_cam``, its rotation and translation sizes)."""

    camera_written: str  # ``camera_key`` of the camera written
    rig_from_cam: np.ndarray  # (4, 4)
    rotation_deg: float
    translation: float

    @classmethod
    def of(cls, camera: Camera, rig: np.ndarray) -> RigCamera:
        from pgt_check.geometry.transforms import rotation_angle_deg

        rig = np.asarray(rig, np.float64)
        return cls(camera_key(camera), rig, rotation_angle_deg(rig[:3, :3]),
                   float(np.linalg.norm(rig[:3, 3])))

    def to_json(self) -> dict[str, Any]:
        return {"camera_written": self.camera_written, "rig_from_cam": self.rig_from_cam.tolist(),
                "rotation_deg": self.rotation_deg, "translation": self.translation}


@dataclass(frozen=True)
class CalibratedRig:
    """What ``write_calibrated_rig`` wrote: summary.json -> ``calibrated_rig``."""

    trajectory_file: str  # relative to the output folder
    cameras: dict[str, RigCamera]  # by the calibration check's camera key
    folder: str = CALIBRATED_DIR

    def to_json(self) -> dict[str, Any]:
        return {"folder": self.folder, "trajectory_file": self.trajectory_file,
                "cameras": {k: c.to_json() for k, c in self.cameras.items()}}
