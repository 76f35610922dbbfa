"""``calibrated_sensors.txt``: the run-level calibration estimate written as camera intrinsics
that a re-run loads (``--sensors``), when the calibration fit is significant.

The estimate (``shared_errors.calibration``, per camera) is ``true_cam_from_checked_cam``: a
rotation ``R``, a focal scale ``s`` and, with ``--calibration-translation``, a translation
``t``. A photo pixel is ``K_s pi(R x + t)`` for a point ``x`` in the checked camera. Written:

* focal lengths ``s * f``;
* the principal point moved to where ``R`` sends the optical axis, ``K_s pi(R e_z)``: the
  rotation about the camera's x / y axes as a principal-point shift (exact at the image
  centre; what remains is the roll, a keystone of second order and the translation);
* in comment lines: what the file cannot express (roll, translation) and the displacement it
  leaves, measured over the image at the evidence's depth (``residual_px``), and the
  ``--camera`` value for formats without a sensors file (TUM, hloc).

Where the run wrote the camera into ``calibrated/`` as a principal-point shift fitted on the
evidence (``correct.calibration.choose_form``: the evidence fits it better than the rotation),
that principal point is written here too. A camera whose estimate the file would leave above
the run-level threshold (a camera-to-sensor translation, a large roll) is not written
(``not_written``): the file would not pass its own re-check; ``calibrated/`` holds it.

The file uses the LaMAR sensors format (``sensor_id, name, camera, MODEL, w, h, params``,
COLMAP pixel convention); for LaMAR inputs the sensor ids are those of the frames.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from pgt_check.common.checks import check_shape
from pgt_check.common.files import atomic_write_text
from pgt_check.correct.calibration import with_focal_scale
from pgt_check.output_layout import OUTPUTS
from pgt_check.types import Camera, opencv_to_colmap_params
from pgt_check.verdict.shared import SharedChecks

logger = logging.getLogger(__name__)

#: calibration statuses that mean a significant error (lower 95 % bound above the threshold)
SIGNIFICANT = ("failed", "finding")


@dataclass(frozen=True)
class CalibratedCamera:
    """One camera's intrinsics with the calibration estimate applied (OpenCV convention)."""

    camera: Camera
    roll_deg: float
    translation: tuple[float, float, float]
    #: mean displacement (px) over a grid of the image that the written intrinsics leave
    residual_px: float
    #: the displacement the estimate itself moves the images by (px, same grid)
    effect_px: float


def parse_camera_key(key: str) -> Camera:
    """The ``Camera`` of a ``measure.record.camera_key`` ('MODEL WxH p1,p2,...')."""
    try:
        model, size, params = key.split(" ")
        w, h = (int(x) for x in size.split("x"))
        return Camera(model, w, h, tuple(float(p) for p in params.split(",")))
    except (ValueError, TypeError) as err:
        raise ValueError(f"not a camera key: {key!r} ({err})") from None


def _project(k: np.ndarray, x: np.ndarray) -> np.ndarray:
    return (x @ k.T)[:, :2] / x[:, 2:3]


def calibrated_camera(
    camera: Camera,
    rotation: np.ndarray,
    focal_scale: float,
    translation: Sequence[float] | None = None,
    depth: float = 1.0,
) -> CalibratedCamera:
    """``camera`` with the estimate applied (module docstring). rotation: (3, 3)
    true_cam_from_checked_cam; depth: where the translation's effect is measured."""
    r = np.asarray(rotation, np.float64)
    check_shape("rotation", r, (3, 3))
    if not (math.isfinite(focal_scale) and focal_scale > 0):
        raise ValueError(f"focal_scale must be positive, got {focal_scale}")
    t = np.zeros(3) if translation is None else np.asarray(translation, np.float64).reshape(3)
    fx, fy = camera.focal
    cx, cy = camera.principal_point
    k = np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1.0]])
    ks = k.copy()
    ks[0, 0] *= focal_scale
    ks[1, 1] *= focal_scale
    axis = r[:, 2]
    cx2 = ks[0, 0] * axis[0] / axis[2] + cx
    cy2 = ks[1, 1] * axis[1] / axis[2] + cy
    k2 = ks.copy()
    k2[0, 2], k2[1, 2] = cx2, cy2
    # the displacement left, over a 9 x 9 grid of the image at ``depth``
    gu, gv = np.meshgrid(np.linspace(0, camera.width - 1, 9), np.linspace(0, camera.height - 1, 9))
    pix = np.c_[gu.ravel(), gv.ravel(), np.ones(gu.size)]
    x = (pix @ np.linalg.inv(k).T) * depth
    truth = _project(ks, x @ r.T + t)
    residual = float(np.mean(np.linalg.norm(_project(k2, x) - truth, axis=1)))
    effect = float(np.mean(np.linalg.norm(_project(k, x) - truth, axis=1)))
    roll = math.degrees(math.atan2(r[1, 0] - r[0, 1], r[0, 0] + r[1, 1]))
    return CalibratedCamera(
        with_focal_scale(camera, focal_scale, (float(cx2), float(cy2))),
        roll, (float(t[0]), float(t[1]), float(t[2])), residual, effect,
    )  # fmt: skip


def _sensor_ids(frame_ids: Sequence[str], n: int) -> list[str]:
    """LaMAR frame ids are 'timestamp/sensor': the sensor ids; else cam0, cam1, ..."""
    ids = sorted({f.rsplit("/", 1)[1] for f in frame_ids if "/" in f})
    return ids if ids else [f"cam{n}"]


def _fitted_camera(rig: Mapping[str, Any] | None, cam_id: str) -> Camera | None:
    """The camera the run wrote into ``calibrated/`` for ``cam_id`` when it wrote the error
    as a principal-point shift fitted on the evidence (``correct.calibration.choose_form``:
    the evidence fits it better than the rotation); None otherwise."""
    entry = ((rig or {}).get("cameras") or {}).get(cam_id)
    if not isinstance(entry, Mapping) or entry.get("form") != "principal_point":
        return None
    try:
        return parse_camera_key(str(entry.get("camera_written")))
    except ValueError:
        return None


def calibrated_sensors_text(
    rows: Sequence[Mapping[str, Any]], shared: SharedChecks | None,
    rig: Mapping[str, Any] | None = None,
) -> tuple[str, dict[str, Any]] | None:
    """(file text, summary entry) for the cameras whose calibration is significant; None when
    none is. ``rows``: judged rows (``frame_id``, ``camera_id``); ``shared``: the run-level
    checks as reported (their calibration entries and threshold); ``rig``: its ``calibrated_rig`` (a camera written there as a fitted
    principal-point shift is written so here too: the file and ``calibrated/`` agree)."""
    calib = shared.calibration if shared is not None else {}
    lines = [
        "# calibrated_sensors.txt: written by pgt-check from the run-level calibration estimate",
        "# (focal x focal_scale; principal point moved to where the camera-to-sensor rotation",
        "# sends the optical axis). Re-run with --sensors calibrated_sensors.txt.",
        "# sensor_id, name, sensor_type, [sensor_params]+",
    ]
    entry: dict[str, Any] = {"file": OUTPUTS.calibrated_sensors, "cameras": {}, "not_written": {}}
    # a camera whose intrinsics would leave more than this is not written: the file would not
    # pass its own re-check (#39)
    limit = shared.threshold_px if shared is not None else None
    n = 0
    for cam_id, e in sorted(calib.items()):
        if e.status not in SIGNIFICANT or e.rotation is None or e.focal_scale is None:
            continue
        try:
            cam = parse_camera_key(cam_id)
        except ValueError as err:
            logger.warning("calibrated sensors: %s", err)
            continue
        frames = [str(r["frame_id"]) for r in rows if r.get("camera_id") == cam_id]
        depth = _median_depth(rows, cam_id)
        cc = calibrated_camera(cam, np.asarray(e.rotation, float), float(e.focal_scale),
                               e.translation, depth)
        fitted = _fitted_camera(rig, cam_id)
        if fitted is not None:  # the fitted shift; what is left: the roll and translation
            from pgt_check.correct.calibration import roll_only

            left = calibrated_camera(fitted, roll_only(np.asarray(e.rotation, float)), 1.0,
                                     e.translation, depth)
            cc = CalibratedCamera(fitted, cc.roll_deg, cc.translation, left.residual_px,
                                  cc.effect_px)
        if isinstance(limit, (int, float)) and cc.residual_px > limit:
            entry["not_written"][cam_id] = (
                f"intrinsics cannot express this estimate: they would leave {cc.residual_px:.2f} "
                f"px of its {cc.effect_px:.2f} px (roll, camera-to-sensor translation), above "
                f"the {limit:.2f} px threshold; calibrated/ holds it exactly")
            continue
        params = opencv_to_colmap_params(cc.camera.model, cc.camera.params)
        ptxt = ", ".join(f"{p:.10g}" for p in params)
        sids = _sensor_ids(frames, n)
        n += 1
        tx, ty, tz = cc.translation
        leaves = (f"the file leaves {cc.residual_px:.2f} px of the estimate's {cc.effect_px:.2f} px "
                f"(mean over the image at depth {depth:.3g})"
                + ("" if fitted is None else "; the principal point is the shift fitted on the "
                   "evidence, as in calibrated/"))
        lines.append(
            f"# {cam_id}: roll {cc.roll_deg:+.4f} deg and camera-to-sensor translation "
            f"({tx:+.5g}, {ty:+.5g}, {tz:+.5g}) scene units are not expressible here; {leaves}"
        )
        camera_arg = f"{cc.camera.model},{cc.camera.width},{cc.camera.height}," + ",".join(
            f"{p:.10g}" for p in params)
        lines.append(f"# --camera {camera_arg}")
        for sid in sids:
            lines.append(f"{sid}, {sid}, camera, {cc.camera.model}, {cc.camera.width}, "
                         f"{cc.camera.height}, {ptxt}")
        entry["cameras"][cam_id] = {
            "sensor_ids": sids,
            "model": cc.camera.model,
            "params_colmap_convention": list(params),
            "roll_deg": cc.roll_deg,
            "translation": list(cc.translation),
            "residual_px": cc.residual_px,
            "effect_px": cc.effect_px,
            # the same intrinsics for formats without a sensors file (TUM, ...): ``--camera``
            "camera_arg": camera_arg,
            "principal_point": "fitted" if fitted is not None else "rotation",
        }
    if not entry["cameras"]:
        if entry["not_written"]:
            logger.info("calibrated sensors not written: %s",
                        "; ".join(entry["not_written"].values()))
        return None
    if not entry["not_written"]:
        del entry["not_written"]
    return "\n".join(lines) + "\n", entry


def _median_depth(rows: Sequence[Mapping[str, Any]], cam_id: str) -> float:
    """Depth at which the translation's effect is measured: the px-per-unit sensitivity says
    nothing of depth, so use 1 scene unit unless rows carry ``acc_depth``."""
    zs = [float(r["acc_depth"]) for r in rows
          if r.get("camera_id") == cam_id and isinstance(r.get("acc_depth"), (int, float))]
    return float(np.median(zs)) if zs else 1.0


def write_calibrated_sensors(
    out: Path, rows: Sequence[Mapping[str, Any]], shared: SharedChecks | None,
    rig: Mapping[str, Any] | None = None,
) -> dict[str, Any] | None:
    """Write (or remove a stale) ``calibrated_sensors.txt`` in ``out``; its summary entry."""
    path = Path(out) / OUTPUTS.calibrated_sensors
    made = calibrated_sensors_text(rows, shared, rig)
    if made is None:
        path.unlink(missing_ok=True)
        return None
    text, entry = made
    atomic_write_text(path, text)
    logger.info("wrote %s (%d camera(s))", path, len(entry["cameras"]))
    return entry
