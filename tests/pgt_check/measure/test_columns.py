"""The flat columns of a measurement (``measure/columns.py``): unique names, every column read
from a full and from a failed record, the deciding path's columns, the timing columns."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from pgt_check.enhance.base import Evidence
from pgt_check.measure import (
    MEASUREMENT_COLUMNS,
    TIMING_COLUMNS,
    EnhanceWhy,
    FrameMeasurement,
    MeasureReason,
    PathMeasurement,
    PoseEstimate,
    Timings,
    failed_measurement,
)
from pgt_check.types import Camera, Frame


def _path(kind: str, err: float | None, inliers: int) -> PathMeasurement:
    ok = err is not None
    return PathMeasurement(
        kind=kind,
        method="render" if kind == "raw" else "reproject",
        evidence=Evidence.ABSOLUTE,
        n_kpts_render=900,
        n_kpts_photo=1000,
        n_matches=200,
        n_inliers=inliers,
        inlier_ratio=inliers / 200,
        reason="" if ok else "too_few_inliers",
        photo_from_render=tuple(map(tuple, np.eye(3))) if ok else None,
        corner_error_px=err,
        shift_dx_px=1.5 if ok else None,
        shift_dy_px=-0.5 if ok else None,
        zoom=1.001 if ok else None,
        reference_id="f2" if kind == "enhanced" else None,
    )


def _frame() -> Frame:
    return Frame("f1", Camera.pinhole(64, 48, 50, 50, 31.5, 23.5), np.eye(4), image_path="a.png")


def _full(verdict_path: str = "enhanced") -> FrameMeasurement:
    return dataclasses.replace(
        failed_measurement(_frame(), MeasureReason.NONE),
        coverage=0.8,
        shading="vertex",
        match_width=64,
        match_height=48,
        raw=_path("raw", None, 8),
        enhanced=_path("enhanced", 3.0, 150),
        enhance_ran=True,
        enhance_why=EnhanceWhy.RAW_FAILED,
        verdict_path=verdict_path,
        pose=PoseEstimate(80, "", 0.01, 0.5, tuple(map(tuple, np.eye(4)))),
        timings=Timings(load=0.1, render=0.2, total=1.0),
    )


def test_column_names_are_unique_and_documented():
    names = [c.name for c in MEASUREMENT_COLUMNS]
    assert len(names) == len(set(names))
    assert names[0] == "frame_id"
    assert all(c.doc.strip() for c in MEASUREMENT_COLUMNS)


def test_timing_columns_are_the_t_columns_and_the_total():
    assert "time_s" in TIMING_COLUMNS and "t_render_s" in TIMING_COLUMNS
    assert all(n.startswith("t_") or n == "time_s" for n in TIMING_COLUMNS)
    assert "corner_error_px" not in TIMING_COLUMNS


def test_columns_of_a_full_record_follow_the_deciding_path():
    row = {c.name: c.get(_full()) for c in MEASUREMENT_COLUMNS}
    assert row["corner_error_px"] == 3.0 and row["n_inliers"] == 150  # the enhanced path
    assert row["shift_dx_px"] == 1.5 and row["zoom"] == 1.001
    assert row["corner_error_px_raw"] is None and row["n_inliers_raw"] == 8
    assert row["shift_dx_px_raw"] is None  # the raw path found no homography
    assert row["homography_reason_raw"] == "too_few_inliers"
    assert row["reference_id"] == "f2"
    assert row["corner_error_px_edges"] is None and row["edge_support"] is None  # no edge path
    assert row["pose_drot_deg"] == 0.5 and row["pose_inliers"] == 80 and row["pose_reason"] == ""
    assert row["t_render_s"] == 0.2 and row["time_s"] == 1.0
    assert row["center"] == [0.0, 0.0, 0.0]
    assert row["n_absolute_points"] == 0
    assert row == _full().row()  # the record's own row is these columns


def test_columns_of_a_failed_record_have_their_defaults():
    m = failed_measurement(_frame(), MeasureReason.IMAGE_MISSING, "gone")
    row = {c.name: c.get(m) for c in MEASUREMENT_COLUMNS}
    assert row["error"] == "image_missing" and row["error_detail"] == "gone"
    assert row["n_matches"] == 0 and row["n_inliers"] == 0 and row["inlier_ratio"] == 0.0
    assert row["homography_reason"] == "" and row["pose_reason"] == ""
    assert row["corner_error_px"] is None and row["pose_dt"] is None


@pytest.mark.parametrize("name", ["error", "error_detail", "center", "homography_reason"])
def test_some_columns_stay_out_of_frames_csv(name):
    (col,) = [c for c in MEASUREMENT_COLUMNS if c.name == name]
    assert not col.csv
