"""The flat columns of a ``FrameMeasurement`` (frames.csv, the report table, JUnit): declared
once here, each with its meaning and how it is read from the typed record."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

FrameMeasurement = Any  # pgt_check.measure.record.FrameMeasurement (not imported: no cycle)


@dataclass(frozen=True)
class Column:
    """One flat column: name, what it holds (for the docs and the report), and its getter."""

    name: str
    doc: str
    get: Callable[[FrameMeasurement], Any]
    #: written to frames.csv (the others are in the report table data and records only)
    csv: bool = True


def _path_attr(path: str, attr: str, default: Any = None) -> Callable[[FrameMeasurement], Any]:
    """``attr`` of the record's part ``path`` (raw, enhanced, edges, pose, or ``chosen``: the
    deciding path), ``default`` when it is absent."""

    def get(m: FrameMeasurement) -> Any:
        p = getattr(m, path)
        return default if p is None else getattr(p, attr)

    return get


def _path_success_attr(path: str, attr: str) -> Callable[[FrameMeasurement], Any]:
    """``attr`` of path ``path`` where it found a homography (None otherwise)."""

    def get(m: FrameMeasurement) -> Any:
        p = getattr(m, path)
        return None if p is None or not p.success else getattr(p, attr)

    return get


def _timing(attr: str) -> Callable[[FrameMeasurement], Any]:
    return lambda m: getattr(m.timings, attr)


def _path_stats(path: str, what: str) -> tuple[Column, ...]:
    """Matches, inliers, inlier ratio and no-homography reason of one feature path."""
    return (
        Column(f"n_matches_{path}", f"matches of the {what}", _path_attr(path, "n_matches")),
        Column(f"n_inliers_{path}", f"inliers of the {what}", _path_attr(path, "n_inliers")),
        Column(
            f"inlier_ratio_{path}", f"inlier ratio of the {what}", _path_attr(path, "inlier_ratio")
        ),
        Column(
            f"homography_reason_{path}",
            f"why the {what} has no homography",
            _path_attr(path, "reason", ""),
            csv=False,
        ),
    )


#: the measurement's flat columns, in frames.csv order (the verdict columns come from
#: ``pgt_check.verdict``; ``report.outputs.FRAME_COLUMNS`` puts them together)
MEASUREMENT_COLUMNS: tuple[Column, ...] = (
    Column("frame_id", "frame id (unique within the trajectory)", lambda m: m.frame_id),
    Column("timestamp", "timestamp as given by the trajectory", lambda m: m.timestamp),
    Column("image_path", "photo path as given by the trajectory", lambda m: m.image_path),
    Column("error", "why the frame could not be measured", lambda m: m.error.value, csv=False),
    Column("error_detail", "details of the measurement error", lambda m: m.error_detail, csv=False),
    Column(
        "corner_error_px",
        "corner error of the deciding path, photo px",
        _path_attr("chosen", "corner_error_px"),
    ),
    Column("n_matches", "matches of the deciding path", _path_attr("chosen", "n_matches", 0)),
    Column("n_inliers", "homography inliers of the deciding path", _path_attr("chosen", "n_inliers", 0)),
    Column(
        "inlier_ratio", "inliers / matches of the deciding path", _path_attr("chosen", "inlier_ratio", 0.0)
    ),
    Column(
        "homography_reason",
        "why the deciding path has no homography",
        _path_attr("chosen", "reason", ""),
        csv=False,
    ),
    Column("coverage", "share of the render covered by the mesh", lambda m: m.coverage),
    Column(
        "shift_dx_px",
        "mean corner shift x of the deciding path, px",
        _path_success_attr("chosen", "shift_dx_px"),
    ),
    Column(
        "shift_dy_px",
        "mean corner shift y of the deciding path, px",
        _path_success_attr("chosen", "shift_dy_px"),
    ),
    Column("zoom", "warped / original diagonal of the deciding path", _path_success_attr("chosen", "zoom")),
    Column(
        "n_kpts_render", "keypoints in the render (deciding path)", _path_attr("chosen", "n_kpts_render")
    ),
    Column("n_kpts_photo", "keypoints in the photo (deciding path)", _path_attr("chosen", "n_kpts_photo")),
    Column("width", "photo width, px", lambda m: m.width),
    Column("height", "photo height, px", lambda m: m.height),
    Column("match_width", "width matched at, px", lambda m: m.match_width),
    Column("match_height", "height matched at, px", lambda m: m.match_height),
    Column("shading", "how the render got its colour", lambda m: m.shading),
    Column(
        "corner_error_px_raw",
        "corner error of the raw render, px",
        _path_attr("raw", "corner_error_px"),
    ),
    Column(
        "shift_dx_px_raw", "mean corner shift x of the raw render, px", _path_success_attr("raw", "shift_dx_px")
    ),
    Column(
        "shift_dy_px_raw", "mean corner shift y of the raw render, px", _path_success_attr("raw", "shift_dy_px")
    ),
    Column("zoom_raw", "zoom of the raw render", _path_success_attr("raw", "zoom")),
    *_path_stats("raw", "raw render"),
    Column(
        "corner_error_px_enhanced",
        "corner error of the enhanced render, px",
        _path_attr("enhanced", "corner_error_px"),
    ),
    *_path_stats("enhanced", "enhanced render"),
    Column(
        "corner_error_px_edges",
        "corner error of the geometric-edge alignment, px",
        _path_attr("edges", "corner_error_px"),
    ),
    Column(
        "edge_support",
        "share of the render's geometric edges on a photo edge after alignment",
        _path_attr("edges", "inlier_ratio"),
    ),
    Column(
        "edge_reason",
        "why the edge path is not verifiable (ambiguous, not_significant, ...)",
        _path_attr("edges", "reason", ""),
    ),
    Column("enhanced", "whether the enhanced path ran", lambda m: m.enhance_ran),
    Column("enhanced_why", "why it ran or not", lambda m: m.enhanced_why),
    Column(
        "verdict_path",
        "deciding path: more inliers (raw / enhanced), or edges when no feature path aligned",
        lambda m: m.verdict_path,
    ),
    Column(
        "reference_id",
        "reference frame of the enhanced path",
        _path_attr("enhanced", "reference_id"),
    ),
    Column("pose_dt", "PnP camera-centre correction, scene units", _path_attr("pose", "dt")),
    Column("pose_drot_deg", "PnP rotation correction, deg", _path_attr("pose", "drot_deg")),
    Column("pose_inliers", "PnP inliers", _path_attr("pose", "n_inliers")),
    Column(
        "pose_reason",
        "why the PnP estimate failed",
        _path_attr("pose", "reason", ""),
        csv=False,
    ),
    Column("t_load_s", "time: photo loading, s", _timing("load")),
    Column("t_render_s", "time: rendering, s", _timing("render")),
    Column("t_match_s", "time: matching (all paths), s", _timing("match")),
    Column("t_homography_s", "time: homographies (all paths), s", _timing("homography")),
    Column("t_enhance_s", "time: enhancement, s", _timing("enhance")),
    Column("t_edges_s", "time: geometric-edge path, s", _timing("edges")),
    Column("t_pose_s", "time: PnP, s", _timing("pose")),
    Column("time_s", "time: whole frame, s", _timing("total")),
    Column("center", "camera centre (world)", lambda m: list(m.center), csv=False),
    Column(
        "n_absolute_points",
        "2D-3D correspondences this frame adds to the run-level checks",
        lambda m: 0 if m.evidence is None else len(m.evidence),
    ),
)

#: timing columns (frames.csv; left out when comparing runs)
TIMING_COLUMNS: tuple[str, ...] = tuple(
    c.name for c in MEASUREMENT_COLUMNS if c.name.startswith("t_") or c.name == "time_s"
)
