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


#: the parts of a record a column reads: its paths (``record.PATH_NAMES``), the PnP estimate
#: and the deciding path
PARTS = ("raw", "enhanced", "edges", "pose", "chosen")


def _part(m: FrameMeasurement, name: str) -> Any:
    if name == "pose":
        return m.pose
    if name == "chosen":
        return m.chosen
    return m.path(name)


def _checked_part(name: str) -> str:
    if name not in PARTS:
        raise ValueError(f"no record part {name!r} (one of {', '.join(PARTS)})")
    return name


def _path_attr(path: str, attr: str, default: Any = None) -> Callable[[FrameMeasurement], Any]:
    """``attr`` of the record's part ``path`` (raw, enhanced, edges, pose, or ``chosen``: the
    deciding path), ``default`` when it is absent."""
    _checked_part(path)

    def get(m: FrameMeasurement) -> Any:
        p = _part(m, path)
        return default if p is None else getattr(p, attr)

    return get


def _path_success_attr(path: str, attr: str) -> Callable[[FrameMeasurement], Any]:
    """``attr`` of path ``path`` where it found a homography (None otherwise)."""
    _checked_part(path)

    def get(m: FrameMeasurement) -> Any:
        p = _part(m, path)
        return None if p is None or not p.success else getattr(p, attr)

    return get


#: the headline columns (frames.csv, the report table and its sorting, JUnit, the summary's
#: median): name -> how to read it from a named path of the record. The measurement fills them
#: from ``chosen`` (the path with more inliers); the verdict stage fills them from the path the
#: verdict rests on (``headline_values``), so a frame never shows another path's error
_HEADLINE: dict[str, Callable[[str], Callable[[FrameMeasurement], Any]]] = {
    "corner_error_px": lambda p: _path_attr(p, "corner_error_px"),
    "n_matches": lambda p: _path_attr(p, "n_matches", 0),
    "n_inliers": lambda p: _path_attr(p, "n_inliers", 0),
    "inlier_ratio": lambda p: _path_attr(p, "inlier_ratio", 0.0),
    "homography_reason": lambda p: _path_attr(p, "reason", ""),
    "shift_dx_px": lambda p: _path_success_attr(p, "shift_dx_px"),
    "shift_dy_px": lambda p: _path_success_attr(p, "shift_dy_px"),
    "zoom": lambda p: _path_success_attr(p, "zoom"),
    "n_kpts_render": lambda p: _path_attr(p, "n_kpts_render"),
    "n_kpts_photo": lambda p: _path_attr(p, "n_kpts_photo"),
}

#: names of the headline columns (``_HEADLINE``)
HEADLINE_COLUMNS: tuple[str, ...] = tuple(_HEADLINE)


def headline_values(m: FrameMeasurement, path: str) -> dict[str, Any]:
    """The headline columns read from the record's path ``path`` (raw, enhanced, edges)."""
    if path not in ("raw", "enhanced", "edges"):
        raise ValueError(f"unknown path {path!r} (raw, enhanced, edges)")
    return {name: get(path)(m) for name, get in _HEADLINE.items()}


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
        "corner error of the path the verdict rests on (decided_by; the one with more inliers "
        "before judging), as the verdict compared it, photo px",
        _HEADLINE["corner_error_px"]("chosen"),
    ),
    Column("n_matches", "matches of the deciding path", _HEADLINE["n_matches"]("chosen")),
    Column("n_inliers", "homography inliers of the deciding path", _HEADLINE["n_inliers"]("chosen")),
    Column(
        "inlier_ratio", "inliers / matches of the deciding path", _HEADLINE["inlier_ratio"]("chosen")
    ),
    Column(
        "homography_reason",
        "why the deciding path has no homography",
        _HEADLINE["homography_reason"]("chosen"),
        csv=False,
    ),
    Column("coverage", "share of the render covered by the mesh", lambda m: m.coverage),
    Column(
        "shift_dx_px",
        "mean corner shift x of the deciding path, px",
        _HEADLINE["shift_dx_px"]("chosen"),
    ),
    Column(
        "shift_dy_px",
        "mean corner shift y of the deciding path, px",
        _HEADLINE["shift_dy_px"]("chosen"),
    ),
    Column("zoom", "warped / original diagonal of the deciding path", _HEADLINE["zoom"]("chosen")),
    Column(
        "n_kpts_render", "keypoints in the render (deciding path)", _HEADLINE["n_kpts_render"]("chosen")
    ),
    Column("n_kpts_photo", "keypoints in the photo (deciding path)", _HEADLINE["n_kpts_photo"]("chosen")),
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
