"""The per-frame measurement: one typed, frozen record per frame (stage 1 of a run).

``FrameMeasurement`` holds what was measured for one frame: the raw path (render vs photo),
the enhanced path (if one ran), the pose estimate and the timings. It is stored as one JSON
object per line in ``records.jsonl`` (``to_json`` / ``from_json``; ``SCHEMA_VERSION`` marks the
layout) and never holds a verdict: verdicts are computed from it at output time
(``pgt_check.verdict``). ``row()`` flattens it into the columns of frames.csv, the report table
and JUnit properties; ``measure.columns.MEASUREMENT_COLUMNS`` is the one declaration of them.

Evidence kinds (see ``docs/architecture.md`` and the README): a path is **absolute** evidence
when the image compared with the photo depends only on the mesh and this frame's pose (the raw
render; MaRINeR, which places the reference's appearance by image content), **relative** when it
places a reference photo through the reference's own pose (reprojection).
"""

from __future__ import annotations

import math
from collections.abc import Collection, Mapping
from dataclasses import dataclass, field, fields, replace
from enum import Enum
from typing import Any

from pgt_check.enhance.base import Evidence

#: layout of the JSON records (1 = the flat dicts of pgt-check <= 0.1 before this schema)
SCHEMA_VERSION = 2
#: the measured paths of a frame by name (``FrameMeasurement.path``; ``verdict_path`` and a
#: judgement's ``decided_by`` are one of them)
PATH_NAMES = ("raw", "enhanced", "edges")


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
    #: the geometric-edge path was clear (absolute evidence), so the enhancement was left out
    EDGES_DECISIVE = "edges_decisive"


class OldRecordError(ValueError):
    """A stored record was written by an older pgt-check (another record layout)."""


def _num(x: Any) -> float | None:
    return None if x is None else float(x)


def _matrix(x: Any) -> tuple[tuple[float, ...], ...] | None:
    return None if x is None else tuple(tuple(map(float, r)) for r in x)


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
    edges: float | None = None
    pose: float | None = None
    total: float | None = None

    def to_json(self) -> dict[str, Any]:
        return {f.name: getattr(self, f.name) for f in fields(self)}

    @classmethod
    def from_json(cls, d: Mapping[str, Any]) -> Timings:
        return cls(**{f.name: _num(d.get(f.name)) for f in fields(cls)})


def _g6(x: float) -> float:
    return float(f"{float(x):.6g}")


def source_path(source: str) -> str:
    """The path an evidence source comes from: raw, edges, or enhanced (the source is then the
    enhancer's name, e.g. mariner)."""
    return source if source in ("raw", "edges") else "enhanced"


@dataclass(frozen=True, eq=False)
class AbsoluteEvidence:
    """2D-3D correspondences of one frame from absolute evidence only (the raw render, MaRINeR,
    geometric edges), for the run-level registration / drift / calibration checks.

    pts2d: (N, 2) photo pixels (original resolution, OpenCV convention); pts_cam: (N, 3) the
    matched render points lifted with the render depth, in the checked camera's frame (world
    point = world_from_cam @ pts_cam). ``sources``: which paths contributed; ``counts``: how
    many of the points each source gave, in order (empty in records written before it was
    stored: the split of the points is then unknown).
    """

    sources: tuple[str, ...]
    pts2d: tuple[tuple[float, float], ...]
    pts_cam: tuple[tuple[float, float, float], ...]
    counts: tuple[int, ...] = ()

    def __post_init__(self) -> None:
        if self.counts and (
            len(self.counts) != len(self.sources) or sum(self.counts) != len(self.pts2d)
        ):
            raise ValueError(
                f"evidence counts {self.counts} do not split {len(self.pts2d)} points "
                f"among sources {self.sources}"
            )

    def by_source(self) -> dict[str, tuple[Any, Any]]:
        """source -> (pts2d (n, 2), pts_cam (n, 3)); {} when the split is unknown."""
        import numpy as np

        if not self.counts:
            return {}
        p2 = np.asarray(self.pts2d, np.float64).reshape(-1, 2)
        p3 = np.asarray(self.pts_cam, np.float64).reshape(-1, 3)
        out, start = {}, 0
        for src, n in zip(self.sources, self.counts, strict=True):
            out[src] = (p2[start : start + n], p3[start : start + n])
            start += n
        return out

    def points_of(self, paths: Collection[str]) -> tuple[Any, Any]:
        """(pts2d (n, 2), pts_cam (n, 3)) of the sources whose path (``source_path``) is in
        ``paths``; with the split unknown, all points when every source's path is among them,
        else none."""
        import numpy as np

        split = self.by_source()
        if not split:
            if all(source_path(s) in paths for s in self.sources):
                return (np.asarray(self.pts2d, np.float64).reshape(-1, 2),
                        np.asarray(self.pts_cam, np.float64).reshape(-1, 3))
            return np.zeros((0, 2)), np.zeros((0, 3))
        kept = [v for k, v in split.items() if source_path(k) in paths]
        if not kept:
            return np.zeros((0, 2)), np.zeros((0, 3))
        return np.concatenate([v[0] for v in kept]), np.concatenate([v[1] for v in kept])

    def __len__(self) -> int:
        return len(self.pts2d)

    def __eq__(self, other: object) -> bool:
        return isinstance(other, AbsoluteEvidence) and self.to_json() == other.to_json()

    __hash__ = None  # type: ignore[assignment]

    def to_json(self) -> dict[str, Any]:
        return {
            "sources": list(self.sources),
            "pts2d": [[round(u, 3), round(v, 3)] for u, v in self.pts2d],
            "pts_cam": [[_g6(c) for c in p] for p in self.pts_cam],
            "counts": list(self.counts),
        }

    @classmethod
    def from_json(cls, d: Mapping[str, Any]) -> AbsoluteEvidence:
        return cls(
            tuple(d.get("sources") or ()),
            tuple((float(u), float(v)) for u, v in d.get("pts2d") or ()),
            tuple(tuple(float(c) for c in p) for p in d.get("pts_cam") or ()),  # type: ignore[misc]
            tuple(int(n) for n in d.get("counts") or ()),
        )


@dataclass(frozen=True)
class FrameMeasurement:
    """Everything stage 1 measured for one frame (see the module docstring).

    ``verdict_path`` names the path with more geometric support ("raw" / "enhanced"; "edges"
    when no feature path aligned and the geometric edges did; None when no path was
    measured); the PnP estimate ran on a feature path. ``auto_threshold_px`` is the threshold the
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
    #: the enhanced path through the other references tried (aligned ones only; the one with
    #: the most inliers is ``enhanced``)
    enhanced_alternatives: tuple[PathMeasurement, ...] = ()
    #: the geometric-edge path (absolute; runs where the raw path is not decisive)
    edges: PathMeasurement | None = None
    enhance_ran: bool = False
    enhance_why: EnhanceWhy | None = None
    enhance_why_detail: str = ""
    verdict_path: str | None = None
    pose: PoseEstimate | None = None
    auto_threshold_px: float | None = None
    timings: Timings = field(default_factory=Timings)
    #: the checked pose (4x4 rows) and the photo's pinhole intrinsics (fx, fy, cx, cy; original
    #: pixels) with a key naming the camera: inputs of the run-level checks
    world_from_cam: tuple[tuple[float, ...], ...] | None = None
    intrinsics: tuple[float, float, float, float] | None = None
    camera_id: str = ""
    evidence: AbsoluteEvidence | None = None
    #: hash of what this frame's measurement depends on besides the settings (pose, camera,
    #: image bytes, the references' ones); a stored record whose key differs is measured again
    input_key: str = ""

    # -- access ---------------------------------------------------------------------------
    def path(self, name: str | None) -> PathMeasurement | None:
        """The path named ``name`` (one of ``PATH_NAMES``); None for another name or a path
        that was not measured."""
        if name == "raw":
            return self.raw
        if name == "enhanced":
            return self.enhanced
        if name == "edges":
            return self.edges
        return None

    @property
    def chosen(self) -> PathMeasurement | None:
        """The path named by ``verdict_path``."""
        return self.path(self.verdict_path)

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
            if isinstance(v, (PathMeasurement, PoseEstimate, Timings, AbsoluteEvidence)):
                v = v.to_json()
            elif f.name == "enhanced_alternatives":
                v = [p.to_json() for p in v]
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
            center=tuple(float(c) for c in d["center"]),  # type: ignore[arg-type]  # (3,)
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
            enhanced_alternatives=tuple(
                PathMeasurement.from_json(p) for p in d.get("enhanced_alternatives") or ()
            ),
            edges=None if d.get("edges") is None else PathMeasurement.from_json(d["edges"]),
            enhance_ran=bool(d.get("enhance_ran")),
            enhance_why=None if not why else EnhanceWhy(why),
            enhance_why_detail=str(d.get("enhance_why_detail") or ""),
            verdict_path=d.get("verdict_path"),
            pose=None if d.get("pose") is None else PoseEstimate.from_json(d["pose"]),
            auto_threshold_px=_num(d.get("auto_threshold_px")),
            timings=Timings.from_json(d.get("timings") or {}),
            world_from_cam=_matrix(d.get("world_from_cam")),
            intrinsics=(None if d.get("intrinsics") is None  # (4,): fx, fy, cx, cy
                        else tuple(map(float, d["intrinsics"]))),  # type: ignore[arg-type]
            camera_id=str(d.get("camera_id") or ""),
            evidence=None
            if d.get("evidence") is None
            else AbsoluteEvidence.from_json(d["evidence"]),
            input_key=str(d.get("input_key") or ""),
        )

    # -- flat view ---------------------------------------------------------------------------
    def row(self) -> dict[str, Any]:
        """The flat columns of frames.csv / the report table (see ``COLUMNS``)."""
        from pgt_check.measure.columns import MEASUREMENT_COLUMNS

        return {c.name: c.get(self) for c in MEASUREMENT_COLUMNS}


def failed_measurement(frame: Any, reason: MeasureReason, detail: str = "") -> FrameMeasurement:
    """The measurement of a frame that could not be measured (the one place that builds it).

    ``frame``: a ``pgt_check.types.Frame``.
    """
    cam = frame.camera
    return FrameMeasurement(
        frame_id=frame.frame_id,
        timestamp=frame.timestamp,
        image_path=frame.image_path,
        width=cam.width,
        height=cam.height,
        center=tuple(float(c) for c in frame.center),  # type: ignore[arg-type]  # (3,)
        error=reason,
        error_detail=detail,
        world_from_cam=tuple(tuple(map(float, r)) for r in frame.world_from_cam),
        camera_id=camera_key(cam),
    )


def camera_key(camera: Any) -> str:
    """A readable key that names one physical camera (model, size, parameters)."""
    params = ",".join(f"{p:.6g}" for p in camera.params)
    return f"{camera.model} {camera.width}x{camera.height} {params}"
