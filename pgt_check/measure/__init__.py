"""Stage 1: per-frame measurement (``FrameChecker``) and its typed record (``FrameMeasurement``).

Layering: io / render / match / geometry / enhance -> measure -> verdict -> report.
Importing this package does not import OpenCV, moderngl or torch.
"""

from __future__ import annotations

from pgt_check.measure.checker import FrameChecker, build_frame_checker, pick_references
from pgt_check.measure.columns import MEASUREMENT_COLUMNS, TIMING_COLUMNS
from pgt_check.measure.paths import FrameImages, PathImages, PathResult
from pgt_check.measure.record import (
    SCHEMA_VERSION,
    AbsoluteEvidence,
    EnhanceWhy,
    FrameMeasurement,
    MeasureReason,
    OldRecordError,
    PathMeasurement,
    PoseEstimate,
    Timings,
    failed_measurement,
)

__all__ = [
    "AbsoluteEvidence",
    "MEASUREMENT_COLUMNS",
    "SCHEMA_VERSION",
    "TIMING_COLUMNS",
    "EnhanceWhy",
    "FrameChecker",
    "FrameImages",
    "FrameMeasurement",
    "MeasureReason",
    "OldRecordError",
    "PathImages",
    "PathMeasurement",
    "PathResult",
    "PoseEstimate",
    "Timings",
    "build_frame_checker",
    "failed_measurement",
    "pick_references",
]
