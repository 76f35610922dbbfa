"""The typed per-frame measurement: JSON round trip, old layouts, the flat columns."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from pgt_check.correct.correction import CORRECTION_COLUMNS
from pgt_check.enhance.base import Evidence
from pgt_check.measure import (
    MEASUREMENT_COLUMNS,
    EnhanceWhy,
    FrameMeasurement,
    MeasureReason,
    OldRecordError,
    PathMeasurement,
    PoseEstimate,
    Timings,
    failed_measurement,
)
from pgt_check.report.outputs import FRAME_COLUMNS
from pgt_check.types import Camera, Frame


def _path(kind: str, err: float | None, inliers: int) -> PathMeasurement:
    ok = err is not None
    return PathMeasurement(
        kind=kind, method="render" if kind == "raw" else "reproject",
        evidence=Evidence.ABSOLUTE if kind == "raw" else Evidence.RELATIVE,
        n_kpts_render=900, n_kpts_photo=1000, n_matches=200, n_inliers=inliers,
        inlier_ratio=inliers / 200, reason="" if ok else "too_few_inliers",
        photo_from_render=tuple(map(tuple, np.eye(3) * 1.01)) if ok else None,
        corner_error_px=err, shift_dx_px=1.5 if ok else None, shift_dy_px=-0.5 if ok else None,
        zoom=1.001 if ok else None, reference_id="f2" if kind == "enhanced" else None,
    )


def _full() -> FrameMeasurement:
    return FrameMeasurement(
        frame_id="f1", timestamp=12.5, image_path="img/f1.jpg", width=640, height=480,
        center=(1.0, 2.0, 3.0), coverage=0.8, shading="vertex", match_width=640,
        match_height=480, raw=_path("raw", 12.0, 30), enhanced=_path("enhanced", 3.0, 150),
        enhanced_alternatives=(_path("enhanced", 20.0, 90),),
        enhance_ran=True, enhance_why=EnhanceWhy.RAW_FEW_INLIERS, verdict_path="enhanced",
        pose=PoseEstimate(80, "", 0.01, 0.5, tuple(map(tuple, np.eye(4)))),
        auto_threshold_px=16.0, timings=Timings(load=0.1, render=0.2, total=1.0),
    )


def test_json_round_trip_is_exact():
    m = _full()
    text = json.dumps(m.to_json())  # JSON-serialisable as is
    assert FrameMeasurement.from_json(json.loads(text)) == m


def test_failed_measurement_round_trip_and_reason():
    cam = Camera.pinhole(64, 48, 50, 50, 31.5, 23.5)
    frame = Frame("x", cam, np.eye(4), image_path="x.png", timestamp=3.0)
    m = failed_measurement(frame, MeasureReason.WORKER_CRASHED, "died")
    assert FrameMeasurement.from_json(m.to_json()) == m
    row = m.row()
    assert row["error"] == "worker_crashed" and row["corner_error_px"] is None
    assert row["n_matches"] == 0 and row["verdict_path"] is None


def test_old_flat_records_are_refused_with_a_clear_message():
    old = {"frame_id": "f1", "error": "", "corner_error_px": 2.0, "width": 640, "height": 480}
    with pytest.raises(OldRecordError, match="layout 1.*--overwrite"):
        FrameMeasurement.from_json(old)


def test_row_reads_the_deciding_path_and_both_paths():
    row = _full().row()
    assert row["corner_error_px"] == 3.0 and row["n_inliers"] == 150  # enhanced decides
    assert row["corner_error_px_raw"] == 12.0 and row["n_inliers_raw"] == 30
    assert row["corner_error_px_enhanced"] == 3.0 and row["reference_id"] == "f2"
    assert row["enhanced_why"] == "raw_few_inliers" and row["pose_drot_deg"] == 0.5
    assert row["time_s"] == 1.0 and row["t_pose_s"] is None
    raw_failed = FrameMeasurement(
        frame_id="f", timestamp=0, image_path=None, width=10, height=10, center=(0, 0, 0),
        raw=_path("raw", None, 3), enhance_why=EnhanceWhy.RAW_FAILED,
        enhance_why_detail="too_few_inliers", verdict_path="raw",
    )
    r = raw_failed.row()
    assert r["enhanced_why"] == "raw_too_few_inliers" and r["shift_dx_px_raw"] is None
    assert r["homography_reason"] == "too_few_inliers"


def test_columns_are_declared_once_and_feed_frames_csv():
    names = [c.name for c in MEASUREMENT_COLUMNS]
    assert len(names) == len(set(names))
    from pgt_check.verdict import VERDICT_COLUMNS
    from pgt_check.verdict.frame_bounds import ACCURACY_COLUMNS

    csv_measured = [n for n in FRAME_COLUMNS if n not in VERDICT_COLUMNS
                    and n not in ACCURACY_COLUMNS and n not in CORRECTION_COLUMNS]
    assert csv_measured == [c.name for c in MEASUREMENT_COLUMNS if c.csv]
    assert all(c.doc for c in MEASUREMENT_COLUMNS)


def test_non_finite_floats_are_stored_as_null():
    m = FrameMeasurement(frame_id="f", timestamp=0, image_path=None, width=10, height=10,
                         center=(0, 0, 0), coverage=math.nan)
    assert m.to_json()["coverage"] is None
