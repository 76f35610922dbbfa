"""The per-frame measurement: one typed, frozen record per frame (stage 1 of a run).

``FrameMeasurement`` holds what was measured for one frame: the raw path (render vs photo),
the enhanced path (if one ran), the pose estimate and the timings. It is stored as one JSON
object per line in ``records.jsonl`` (``to_json`` / ``from_json``; ``SCHEMA_VERSION`` marks the
layout) and never holds a verdict: verdicts are computed from it at output time
(``pgt_check.verdict``). ``row()`` flattens it into the columns of frames.csv, the report table
and JUnit properties; ``COLUMNS`` is the one declaration of those columns.

Evidence kinds (see ``docs/architecture.md`` and the README): a path is **absolute** evidence
when the image compared with the photo depends only on the mesh and this frame's pose (the raw
render; MaRINeR, which places the reference's appearance by image content), **relative** when it
places a reference photo through the reference's own pose (reprojection).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, fields, replace
from enum import Enum
from typing import Any

from pgt_check.enhance.base import Evidence

#: layout of the JSON records (1 = the flat dicts of pgt-check <= 0.1 before this schema)
SCHEMA_VERSION = 2


class MeasureReason(str, Enum):
    """Why a frame has no (complete) measurement. The value is the machine-readable reason."""

    NONE = ""
    IMAGE_MISSING = "image_missing"
    IMAGE_UNREADABLE = "image_unreadable"
    LOW_COVERAGE = "low_coverage"
    INTERNAL_ERROR = "internal_error"
    WORKER_CRASHED = "worker_crashed"
    #: the photo's pixel size does not fit its camera (other aspect, or scaled > 8x)
    IMAGE_SIZE_MISMATCH = "image_size_mismatch"
    #: the reference photo of the enhanced path cannot be read
    REFERENCE_UNREADABLE = "reference_unreadable"
    #: the image header declares more pixels than ``input.max_image_pixels``
    PIXEL_CAP_EXCEEDED = "pixel_cap_exceeded"


class EnhanceWhy(str, Enum):
    """Why the enhanced path ran or did not (``raw_failed`` carries the homography reason)."""

    MODE_NEVER = "mode_never"
    MODE_ALWAYS = "mode_always"
    RAW_FAILED = "raw_failed"
    RAW_FEW_INLIERS = "raw_few_inliers"
    RAW_NEAR_THRESHOLD = "raw_near_threshold"
    RAW_DECISIVE = "raw_decisive"
    NO_REFERENCE = "no_reference"


class OldRecordError(ValueError):
    """A stored record was written by an older pgt-check (another record layout)."""


def _num(x: Any) -> float | None:
    return None if x is None else float(x)


@dataclass(frozen=True)
class PathMeasurement:
    """Matching + homography of one image (raw render or enhanced render) against the photo.

    Pixels are those of the original photo (the homography was scaled back from the matching
    size). ``reason`` is the homography failure reason ("" on success).
    """

    kind: str  # "raw" | "enhanced"
    method: str  # "render" (raw) or the enhancement method ("reproject", "mariner")
    evidence: Evidence
    n_kpts_render: int
    n_kpts_photo: int
    n_matches: int
    n_inliers: int
    inlier_ratio: float
    reason: str
    photo_from_render: tuple[tuple[float, ...], ...] | None = None
    corner_error_px: float | None = None
    shift_dx_px: float | None = None
    shift_dy_px: float | None = None
    zoom: float | None = None
    reference_id: str | None = None

    @property
    def success(self) -> bool:
        return self.photo_from_render is not None

    def to_json(self) -> dict[str, Any]:
        d = {f.name: getattr(self, f.name) for f in fields(self)}
        d["evidence"] = self.evidence.value
        return d

    @classmethod
    def from_json(cls, d: Mapping[str, Any]) -> PathMeasurement:
        h = d.get("photo_from_render")
        return cls(
            kind=str(d["kind"]),
            method=str(d["method"]),
            evidence=Evidence(d["evidence"]),
            n_kpts_render=int(d["n_kpts_render"]),
            n_kpts_photo=int(d["n_kpts_photo"]),
            n_matches=int(d["n_matches"]),
            n_inliers=int(d["n_inliers"]),
            inlier_ratio=float(d["inlier_ratio"]),
            reason=str(d.get("reason") or ""),
            photo_from_render=None if h is None else tuple(tuple(map(float, r)) for r in h),
            corner_error_px=_num(d.get("corner_error_px")),
            shift_dx_px=_num(d.get("shift_dx_px")),
            shift_dy_px=_num(d.get("shift_dy_px")),
            zoom=_num(d.get("zoom")),
            reference_id=d.get("reference_id"),
        )


@dataclass(frozen=True)
class PoseEstimate:
    """PnP estimate of the photo's pose from lifted render keypoints (see geometry.pnp)."""

    n_inliers: int
    reason: str  # "" on success
    dt: float | None = None  # camera-centre distance, scene units
    drot_deg: float | None = None
    #: the estimated pose (4x4 rows) on success
    world_from_cam: tuple[tuple[float, ...], ...] | None = None

    def to_json(self) -> dict[str, Any]:
        return {f.name: getattr(self, f.name) for f in fields(self)}

    @classmethod
    def from_json(cls, d: Mapping[str, Any]) -> PoseEstimate:
        m = d.get("world_from_cam")
        return cls(
            n_inliers=int(d.get("n_inliers") or 0),
            reason=str(d.get("reason") or ""),
            dt=_num(d.get("dt")),
            drot_deg=_num(d.get("drot_deg")),
            world_from_cam=None if m is None else tuple(tuple(map(float, r)) for r in m),
        )


@dataclass(frozen=True)
class Timings:
    """Seconds per stage (None = the stage did not run). ``total`` covers the whole frame."""

    load: float | None = None
    render: float | None = None
    match: float | None = None
    homography: float | None = None
    enhance: float | None = None
    pose: float | None = None
    total: float | None = None

    def to_json(self) -> dict[str, Any]:
        return {f.name: getattr(self, f.name) for f in fields(self)}

    @classmethod
    def from_json(cls, d: Mapping[str, Any]) -> Timings:
        return cls(**{f.name: _num(d.get(f.name)) for f in fields(cls)})


@dataclass(frozen=True)
class FrameMeasurement:
    """Everything stage 1 measured for one frame (see the module docstring).

    ``verdict_path`` names the path with more geometric support ("raw" / "enhanced"; None when
    no path was measured); the PnP estimate ran on it. ``auto_threshold_px`` is the threshold the
    ``--enhance auto`` decision used (a later re-judgement with another threshold can see that
    the decision was made under different settings).
    """

    frame_id: str
    timestamp: float | int | None
    image_path: str | None
    width: int
    height: int
    center: tuple[float, float, float]
    error: MeasureReason = MeasureReason.NONE
    error_detail: str = ""
    coverage: float | None = None
    shading: str | None = None
    match_width: int | None = None
    match_height: int | None = None
    raw: PathMeasurement | None = None
    enhanced: PathMeasurement | None = None
    enhance_ran: bool = False
    enhance_why: EnhanceWhy | None = None
    enhance_why_detail: str = ""
    verdict_path: str | None = None
    pose: PoseEstimate | None = None
    auto_threshold_px: float | None = None
    timings: Timings = field(default_factory=Timings)
    #: hash of what this frame's measurement depends on besides the settings (pose, camera,
    #: image bytes, the references' ones); a stored record whose key differs is measured again
    input_key: str = ""

    # -- access ---------------------------------------------------------------------------
    @property
    def chosen(self) -> PathMeasurement | None:
        """The path named by ``verdict_path``."""
        if self.verdict_path == "enhanced":
            return self.enhanced
        if self.verdict_path == "raw":
            return self.raw
        return None

    @property
    def enhanced_why(self) -> str:
        """The enhancement decision as one string (``raw_<reason>`` when raw failed)."""
        if self.enhance_why is None:
            return ""
        if self.enhance_why is EnhanceWhy.RAW_FAILED:
            return f"raw_{self.enhance_why_detail}"
        return self.enhance_why.value

    def with_timings(self, timings: Timings) -> FrameMeasurement:
        return replace(self, timings=timings)

    # -- JSON ------------------------------------------------------------------------------
    def to_json(self) -> dict[str, Any]:
        out: dict[str, Any] = {"schema": SCHEMA_VERSION}
        for f in fields(self):
            v = getattr(self, f.name)
            if isinstance(v, (PathMeasurement, PoseEstimate, Timings)):
                v = v.to_json()
            elif isinstance(v, Enum):
                v = v.value
            elif isinstance(v, float) and not math.isfinite(v):
                v = None
            out[f.name] = v
        return out

    @classmethod
    def from_json(cls, d: Mapping[str, Any]) -> FrameMeasurement:
        """Inverse of ``to_json``; raises ``OldRecordError`` for another record layout."""
        schema = d.get("schema", 1)
        if schema != SCHEMA_VERSION:
            raise OldRecordError(
                f"record of frame {d.get('frame_id')!r} has layout {schema} (this pgt-check "
                f"reads layout {SCHEMA_VERSION}): it was written by another version; measure "
                "again (--overwrite)"
            )
        why = d.get("enhance_why")
        return cls(
            frame_id=str(d["frame_id"]),
            timestamp=d.get("timestamp"),
            image_path=d.get("image_path"),
            width=int(d["width"]),
            height=int(d["height"]),
            center=tuple(float(c) for c in d["center"]),
            error=MeasureReason(d.get("error") or ""),
            error_detail=str(d.get("error_detail") or ""),
            coverage=_num(d.get("coverage")),
            shading=d.get("shading"),
            match_width=d.get("match_width"),
            match_height=d.get("match_height"),
            raw=None if d.get("raw") is None else PathMeasurement.from_json(d["raw"]),
            enhanced=(
                None if d.get("enhanced") is None else PathMeasurement.from_json(d["enhanced"])
            ),
            enhance_ran=bool(d.get("enhance_ran")),
            enhance_why=None if not why else EnhanceWhy(why),
            enhance_why_detail=str(d.get("enhance_why_detail") or ""),
            verdict_path=d.get("verdict_path"),
            pose=None if d.get("pose") is None else PoseEstimate.from_json(d["pose"]),
            auto_threshold_px=_num(d.get("auto_threshold_px")),
            timings=Timings.from_json(d.get("timings") or {}),
            input_key=str(d.get("input_key") or ""),
        )

    # -- flat view ---------------------------------------------------------------------------
    def row(self) -> dict[str, Any]:
        """The flat columns of frames.csv / the report table (see ``COLUMNS``)."""
        return {c.name: c.get(self) for c in MEASUREMENT_COLUMNS}


def failed_measurement(frame: Any, reason: MeasureReason, detail: str = "") -> FrameMeasurement:
    """The measurement of a frame that could not be measured (the one place that builds it).

    ``frame``: a ``pgt_check.types.Frame``.
    """
    return FrameMeasurement(
        frame_id=frame.frame_id,
        timestamp=frame.timestamp,
        image_path=frame.image_path,
        width=frame.camera.width,
        height=frame.camera.height,
        center=tuple(float(c) for c in frame.center),
        error=reason,
        error_detail=detail,
    )


# -- columns -----------------------------------------------------------------------------------
@dataclass(frozen=True)
class Column:
    """One flat column: name, what it holds (for the docs and the report), and its getter."""

    name: str
    doc: str
    get: Callable[[FrameMeasurement], Any]
    #: written to frames.csv (the others are in the report table data and records only)
    csv: bool = True


def _path_attr(path: str, attr: str) -> Callable[[FrameMeasurement], Any]:
    def get(m: FrameMeasurement) -> Any:
        p = getattr(m, path)
        return None if p is None else getattr(p, attr)

    return get


def _chosen_attr(attr: str, default: Any = None) -> Callable[[FrameMeasurement], Any]:
    def get(m: FrameMeasurement) -> Any:
        p = m.chosen
        return default if p is None else getattr(p, attr)

    return get


def _chosen_success_attr(attr: str) -> Callable[[FrameMeasurement], Any]:
    def get(m: FrameMeasurement) -> Any:
        p = m.chosen
        return None if p is None or not p.success else getattr(p, attr)

    return get


def _timing(attr: str) -> Callable[[FrameMeasurement], Any]:
    return lambda m: getattr(m.timings, attr)


def _pose_attr(attr: str) -> Callable[[FrameMeasurement], Any]:
    return lambda m: None if m.pose is None else getattr(m.pose, attr)


def _raw_shift(attr: str) -> Callable[[FrameMeasurement], Any]:
    return lambda m: None if m.raw is None or not m.raw.success else getattr(m.raw, attr)


#: the measurement's flat columns, in frames.csv order (the verdict columns come from
#: ``pgt_check.verdict``; ``report.outputs.FRAME_COLUMNS`` puts them together)
MEASUREMENT_COLUMNS: tuple[Column, ...] = (
    Column("frame_id", "frame id (unique within the trajectory)", lambda m: m.frame_id),
    Column("timestamp", "timestamp as given by the trajectory", lambda m: m.timestamp),
    Column("image_path", "photo path as given by the trajectory", lambda m: m.image_path),
    Column("error", "why the frame could not be measured", lambda m: m.error.value, csv=False),
    Column("error_detail", "details of the measurement error", lambda m: m.error_detail, csv=False),
    Column("corner_error_px", "corner error of the deciding path, photo px",
           _chosen_attr("corner_error_px")),
    Column("n_matches", "matches of the deciding path", _chosen_attr("n_matches", 0)),
    Column("n_inliers", "homography inliers of the deciding path", _chosen_attr("n_inliers", 0)),
    Column("inlier_ratio", "inliers / matches of the deciding path",
           _chosen_attr("inlier_ratio", 0.0)),
    Column("homography_reason", "why the deciding path has no homography",
           _chosen_attr("reason", ""), csv=False),
    Column("coverage", "share of the render covered by the mesh", lambda m: m.coverage),
    Column("shift_dx_px", "mean corner shift x of the deciding path, px",
           _chosen_success_attr("shift_dx_px")),
    Column("shift_dy_px", "mean corner shift y of the deciding path, px",
           _chosen_success_attr("shift_dy_px")),
    Column("zoom", "warped / original diagonal of the deciding path",
           _chosen_success_attr("zoom")),
    Column("n_kpts_render", "keypoints in the render (deciding path)",
           _chosen_attr("n_kpts_render")),
    Column("n_kpts_photo", "keypoints in the photo (deciding path)", _chosen_attr("n_kpts_photo")),
    Column("width", "photo width, px", lambda m: m.width),
    Column("height", "photo height, px", lambda m: m.height),
    Column("match_width", "width matched at, px", lambda m: m.match_width),
    Column("match_height", "height matched at, px", lambda m: m.match_height),
    Column("shading", "how the render got its colour", lambda m: m.shading),
    Column("corner_error_px_raw", "corner error of the raw render, px",
           _path_attr("raw", "corner_error_px")),
    Column("shift_dx_px_raw", "mean corner shift x of the raw render, px",
           _raw_shift("shift_dx_px")),
    Column("shift_dy_px_raw", "mean corner shift y of the raw render, px",
           _raw_shift("shift_dy_px")),
    Column("zoom_raw", "zoom of the raw render", _raw_shift("zoom")),
    Column("n_matches_raw", "matches of the raw render", _path_attr("raw", "n_matches")),
    Column("n_inliers_raw", "inliers of the raw render", _path_attr("raw", "n_inliers")),
    Column("inlier_ratio_raw", "inlier ratio of the raw render",
           _path_attr("raw", "inlier_ratio")),
    Column("homography_reason_raw", "why the raw render has no homography",
           lambda m: "" if m.raw is None else m.raw.reason, csv=False),
    Column("corner_error_px_enhanced", "corner error of the enhanced render, px",
           _path_attr("enhanced", "corner_error_px")),
    Column("n_matches_enhanced", "matches of the enhanced render",
           _path_attr("enhanced", "n_matches")),
    Column("n_inliers_enhanced", "inliers of the enhanced render",
           _path_attr("enhanced", "n_inliers")),
    Column("inlier_ratio_enhanced", "inlier ratio of the enhanced render",
           _path_attr("enhanced", "inlier_ratio")),
    Column("homography_reason_enhanced", "why the enhanced render has no homography",
           lambda m: "" if m.enhanced is None else m.enhanced.reason, csv=False),
    Column("enhanced", "whether the enhanced path ran", lambda m: m.enhance_ran),
    Column("enhanced_why", "why it ran or not", lambda m: m.enhanced_why),
    Column("verdict_path", "path with more inliers (raw / enhanced)", lambda m: m.verdict_path),
    Column("reference_id", "reference frame of the enhanced path",
           _path_attr("enhanced", "reference_id")),
    Column("pose_dt", "PnP camera-centre correction, scene units", _pose_attr("dt")),
    Column("pose_drot_deg", "PnP rotation correction, deg", _pose_attr("drot_deg")),
    Column("pose_inliers", "PnP inliers", _pose_attr("n_inliers")),
    Column("pose_reason", "why the PnP estimate failed",
           lambda m: "" if m.pose is None else m.pose.reason, csv=False),
    Column("t_load_s", "time: photo loading, s", _timing("load")),
    Column("t_render_s", "time: rendering, s", _timing("render")),
    Column("t_match_s", "time: matching (all paths), s", _timing("match")),
    Column("t_homography_s", "time: homographies (all paths), s", _timing("homography")),
    Column("t_enhance_s", "time: enhancement, s", _timing("enhance")),
    Column("t_pose_s", "time: PnP, s", _timing("pose")),
    Column("time_s", "time: whole frame, s", _timing("total")),
    Column("center", "camera centre (world)", lambda m: list(m.center), csv=False),
)

#: timing columns (frames.csv; left out when comparing runs)
TIMING_COLUMNS: tuple[str, ...] = tuple(
    c.name for c in MEASUREMENT_COLUMNS if c.name.startswith("t_") or c.name == "time_s"
)
