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

Which form: the estimator models the error as a camera rotation, which moves the images like
a principal-point shift near the centre but not at the edges (a rotation of 0.8 deg at 65 deg
field of view differs from a 4 px shift by up to 1.4 px there), and the views rarely tell the
two apart. Written as a rotation, a principal-point error was left as that pattern and its own
re-check failed (#39). So, given the run's measurements, each camera is written in the form
that fits the pooled evidence of its frames better (``choose_form``): ``rotation`` (the rig
rotation, intrinsics as given but the focal length) or ``principal_point`` (the principal point
shift fitted on the evidence and the focal length in ``sensors.txt``, the rig keeping only the
roll and the translation).
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from pgt_check.geometry.transforms import invert_rigid
from pgt_check.measure.record import camera_key
from pgt_check.output_layout import OUTPUTS
from pgt_check.types import CAMERA_MODELS, Camera, Trajectory
from pgt_check.verdict.shared import SharedChecks
from pgt_check.verdict.shared_results import CalibrationCheck
from pgt_check.verdict.status import FAILED, FINDING

logger = logging.getLogger(__name__)


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


#: the written forms of a camera's calibration error (module docstring)
FORMS = ("rotation", "principal_point")
#: residuals above this many px are capped when the forms are compared (outliers, other errors)
FORM_RESIDUAL_CAP_PX = 5.0


def roll_only(rotation: np.ndarray) -> np.ndarray:
    """(3, 3) the rotation about the optical axis (z) of ``rotation``: its roll."""
    r = np.asarray(rotation, np.float64)
    roll = np.arctan2(r[1, 0] - r[0, 1], r[0, 0] + r[1, 1])
    c, s = np.cos(roll), np.sin(roll)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _predict(k: np.ndarray, rotation: np.ndarray, t: np.ndarray, pts_cam: np.ndarray
             ) -> np.ndarray:
    """(N, 2) pixels of checked-camera points (N, 3) in a camera rotated and moved by
    (rotation, t) (``true_cam_from_checked_cam``) with intrinsics ``k`` (3, 3)."""
    x = pts_cam @ rotation.T + t
    z = np.where(np.abs(x[:, 2:3]) < 1e-9, 1e-9, x[:, 2:3])
    return (x[:, :2] / z) @ k[:2, :2].T + k[:2, 2]


@dataclass(frozen=True)
class WrittenForm:
    """A camera's calibration estimate as it is written: the camera (intrinsics of the photos)
    and ``rig_from_cam`` (4, 4); ``form`` one of ``FORMS``; ``residual_px`` the mean (capped)
    displacement it leaves on the pooled evidence (None without evidence)."""

    form: str
    camera: Camera
    rig_from_cam: np.ndarray
    residual_px: float | None = None


def _pooled_evidence(measurements: Sequence[Any], key: str) -> tuple[np.ndarray, np.ndarray]:
    """(pts_cam (N, 3), pts2d (N, 2)) of the frames of camera ``key`` with absolute evidence."""
    cams, pixels = [], []
    for m in measurements:
        ev = getattr(m, "evidence", None)
        if ev is None or getattr(m, "camera_id", None) != key or not len(ev.pts2d):
            continue
        cams.append(np.asarray(ev.pts_cam, np.float64).reshape(-1, 3))
        pixels.append(np.asarray(ev.pts2d, np.float64).reshape(-1, 2))
    if not cams:
        return np.zeros((0, 3)), np.zeros((0, 2))
    return np.concatenate(cams), np.concatenate(pixels)


def choose_form(camera: Camera, entry: CalibrationCheck,
                measurements: Sequence[Any] | None = None) -> WrittenForm:
    """``camera``'s significant calibration estimate ``entry`` in the form the pooled evidence
    of its frames (``measurements``' absolute evidence) fits better (module docstring). Without
    evidence: the rotation (the estimate as it is)."""
    s = float(entry.focal_scale or 1.0)
    rotation = np.asarray(entry.rotation, np.float64)
    t = np.zeros(3) if entry.translation is None else \
        np.asarray(entry.translation, np.float64).reshape(3)
    scaled = with_focal_scale(camera, s)
    rig = WrittenForm("rotation", scaled, rig_from_cam(entry))
    pts_cam, pts2d = _pooled_evidence(measurements or (), camera_key(camera))
    fx, fy = camera.focal
    cx, cy = camera.principal_point
    k = np.array([[fx * s, 0.0, cx], [0.0, fy * s, cy], [0.0, 0.0, 1.0]])
    roll = roll_only(rotation)
    if len(pts2d) < 8:  # no evidence to fit the shift on: where the rotation sends the axis
        return rig
    front = (pts_cam @ rotation.T + t)[:, 2] > 1e-6
    pts_cam, pts2d = pts_cam[front], pts2d[front]
    if len(pts2d) < 8:
        return rig

    def residual(kk: np.ndarray, r: np.ndarray) -> float:
        d = np.linalg.norm(_predict(kk, r, t, pts_cam) - pts2d, axis=1)
        return float(np.mean(np.minimum(d, FORM_RESIDUAL_CAP_PX)))

    # the principal point shift that best explains the evidence with the roll and translation
    # (the median offset of the points that are not outliers of the rotation form)
    offset = pts2d - _predict(k, roll, t, pts_cam)
    near = np.linalg.norm(pts2d - _predict(k, rotation, t, pts_cam), axis=1) \
        < FORM_RESIDUAL_CAP_PX
    shift = np.median(offset[near] if near.sum() >= 8 else offset, axis=0)
    k_pp = k.copy()
    k_pp[:2, 2] += shift
    pp_camera = with_focal_scale(camera, s, (cx + float(shift[0]), cy + float(shift[1])))
    m = np.eye(4)
    m[:3, :3], m[:3, 3] = roll, t
    pp = WrittenForm("principal_point", pp_camera, invert_rigid(m), residual(k_pp, roll))
    rig = WrittenForm("rotation", scaled, rig.rig_from_cam, residual(k, rotation))
    return pp if pp.residual_px < rig.residual_px else rig  # type: ignore[operator]  # both set


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
    trajectory: Trajectory, shared: SharedChecks | None, out: str | Path,
    measurements: Sequence[Any] | None = None,
) -> CalibratedRig | None:
    """Write ``out/calibrated/`` (module docstring) and return what it holds; None (and an
    earlier run's files removed) when no camera's calibration is significant.
    ``measurements``: the run's (their absolute evidence picks each camera's written form,
    ``choose_form``; without them the rotation is written)."""
    from pgt_check.io.lamar_write import write_lamar

    folder = Path(out) / OUTPUTS.calibrated_dir
    cals = significant_calibrations(shared)
    cams = {f.camera for f in trajectory.frames}
    rigs: dict[Camera, tuple[Camera, np.ndarray]] = {}
    forms: dict[Camera, WrittenForm] = {}
    for cam in cams:
        entry = cals.get(camera_key(cam))
        if entry is not None:
            forms[cam] = choose_form(cam, entry, measurements)
            rigs[cam] = (forms[cam].camera, forms[cam].rig_from_cam)
    if not rigs:
        for name in OUTPUTS.calibrated_files:
            (folder / name).unlink(missing_ok=True)
        if folder.is_dir() and not any(folder.iterdir()):
            folder.rmdir()
        return None
    files = write_lamar(trajectory, folder, rigs=rigs)
    logger.info("wrote %s (the calibration estimate as a rig, %d camera(s))", folder, len(rigs))
    return CalibratedRig(
        trajectory_file=f"{OUTPUTS.calibrated_dir}/{files['trajectories'].name}",
        cameras={camera_key(c): RigCamera.of(e, r, forms[c].form, forms[c].residual_px)
                 for c, (e, r) in rigs.items()},
    )


@dataclass(frozen=True)
class RigCamera:
    """One camera of the rig session: the camera written (focal lengths scaled) and where it
    sits in the posed sensor (``rig_from_cam``, its rotation and translation sizes)."""

    camera_written: str  # ``camera_key`` of the camera written
    rig_from_cam: np.ndarray  # (4, 4)
    rotation_deg: float
    translation: float
    form: str = "rotation"  # one of ``FORMS``
    residual_px: float | None = None  # what the form leaves on the evidence (``choose_form``)

    @classmethod
    def of(cls, camera: Camera, rig: np.ndarray, form: str = "rotation",
           residual_px: float | None = None) -> RigCamera:
        from pgt_check.geometry.transforms import rotation_angle_deg

        rig = np.asarray(rig, np.float64)
        return cls(camera_key(camera), rig, rotation_angle_deg(rig[:3, :3]),
                   float(np.linalg.norm(rig[:3, 3])), form, residual_px)

    def to_json(self) -> dict[str, Any]:
        return {"camera_written": self.camera_written, "rig_from_cam": self.rig_from_cam.tolist(),
                "rotation_deg": self.rotation_deg, "translation": self.translation,
                "form": self.form, "residual_px": self.residual_px}


@dataclass(frozen=True)
class CalibratedRig:
    """What ``write_calibrated_rig`` wrote: summary.json -> ``calibrated_rig``."""

    trajectory_file: str  # relative to the output folder
    cameras: dict[str, RigCamera]  # by the calibration check's camera key
    folder: str = OUTPUTS.calibrated_dir

    def to_json(self) -> dict[str, Any]:
        return {"folder": self.folder, "trajectory_file": self.trajectory_file,
                "cameras": {k: c.to_json() for k, c in self.cameras.items()}}
