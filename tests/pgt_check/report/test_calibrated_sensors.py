"""calibrated_sensors.txt: a significant calibration estimate written as intrinsics and read
back by the LaMAR reader."""

from __future__ import annotations

import math

import numpy as np
import pytest

from pgt_check.geometry.reprojection import so3_exp
from pgt_check.io.lamar import read_sensors
from pgt_check.output_layout import OUTPUTS
from pgt_check.report.calibrated_sensors import (
    calibrated_camera,
    parse_camera_key,
    write_calibrated_sensors,
)
from pgt_check.types import Camera
from pgt_check.verdict.shared import SharedChecks

CAM = Camera.pinhole(640, 480, 525.0, 525.0, 319.5, 239.5)
KEY = "PINHOLE 640x480 525,525,319.5,239.5"


def test_camera_key_parses():
    assert parse_camera_key(KEY) == CAM
    with pytest.raises(ValueError):
        parse_camera_key("nonsense")


def test_rotation_about_x_y_becomes_the_principal_point():
    r = so3_exp(np.radians([0.0, 0.5, 0.0]))  # about y: the image moves along x
    cc = calibrated_camera(CAM, r, 1.01)
    fx, fy = cc.camera.focal
    cx, cy = cc.camera.principal_point
    assert fx == pytest.approx(525 * 1.01) and fy == pytest.approx(525 * 1.01)
    assert cx - 319.5 == pytest.approx(525 * 1.01 * math.tan(math.radians(0.5)), rel=1e-6)
    assert cy == pytest.approx(239.5)
    # what a principal point cannot hold: the keystone of the rotation (second order in the
    # image position), under a fifth of the effect here
    assert cc.effect_px > 4 and cc.residual_px < 0.2 * cc.effect_px
    # the roll is not an intrinsic: reported, and it is what is left
    cc = calibrated_camera(CAM, so3_exp(np.radians([0.0, 0.0, 0.3])), 1.0)
    assert cc.roll_deg == pytest.approx(0.3, abs=1e-6) and cc.residual_px > 0.5


def _shared_json(status: str) -> dict:
    r = so3_exp(np.radians([-0.2, 0.8, 0.1]))
    return {"calibration": {KEY: {"status": status, "rotation": r.tolist(),
                                  "focal_scale": 0.998, "translation": None}}}


def _shared(status: str) -> SharedChecks:
    return SharedChecks.from_summary(_shared_json(status))


def test_written_file_reads_back_and_a_stale_one_is_removed(tmp_path):
    rows = [{"frame_id": f"{i}/cam0", "camera_id": KEY, "acc_depth": 2.0} for i in range(3)]
    entry = write_calibrated_sensors(tmp_path, rows, _shared("finding"))
    assert entry is not None and entry["cameras"][KEY]["sensor_ids"] == ["cam0"]
    cams, ids = read_sensors(tmp_path / OUTPUTS.calibrated_sensors)
    cam = cams["cam0"]
    want = calibrated_camera(CAM, np.asarray(_shared_json("finding")["calibration"][KEY]["rotation"]),
                             0.998, depth=2.0).camera
    np.testing.assert_allclose(cam.params, want.params, rtol=1e-9)
    # a calibration within the threshold writes nothing, and removes an earlier file
    assert write_calibrated_sensors(tmp_path, rows, _shared("passed")) is None
    assert not (tmp_path / OUTPUTS.calibrated_sensors).exists()
