"""The geometric-edge path of one frame: the render's silhouettes and creases (from its depth,
never its shading) aligned with the photo's edges (``pgt_check.geometry.edges``).

It is absolute evidence (it depends only on the mesh and this frame's pose) and needs no
texture, so it verifies frames of colourless or textureless meshes where feature matching finds
nothing, and it adds 2D-3D evidence to the run-level checks.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any

import numpy as np

from pgt_check.config import EdgeConfig
from pgt_check.enhance.base import Evidence
from pgt_check.measure.paths import MAX_EVIDENCE_POINTS, PathResult, absolute_evidence
from pgt_check.measure.record import EnhanceWhy, FrameMeasurement, PathMeasurement
from pgt_check.measure.steps import Clock, MeasuringConfig, Working, replace_measurement
from pgt_check.render.base import Render
from pgt_check.types import Camera


@dataclass(frozen=True, eq=False)
class EdgePath:
    """The stored result and the matched edge points (pixels of the edge path's working size,
    whose camera and scale (working / original) it keeps) for evidence."""

    measurement: PathMeasurement
    render_points: np.ndarray  # (M, 2)
    photo_points: np.ndarray  # (M, 2)
    depth: np.ndarray  # (M,)
    cam_w: Camera
    scale: tuple[float, float]


def measure_edges(
    render: Render,
    photo_w: np.ndarray,
    cam_w: Camera,
    scale: tuple[float, float],
    camera: Camera,
    config: EdgeConfig,
    threshold_px: float | None = None,
) -> EdgePath:
    """Align the render's geometric edges with the photo's (both at working size).

    ``config.select_model`` "fallback": the fixed model first; where its alignment does not
    pass (refused, or its corner error above ``threshold_px``, original pixels), the frame's
    edges choose the model by cross-validation and that alignment is the measurement
    (``method`` "edges:<model>"). The fixed alignment's matched points stay the evidence
    wherever it was accepted (a simpler model's points bias the pooled registration fit)."""
    from pgt_check.geometry.edges import RenderEdgeConfig, geometric_edges, photo_edges

    redges = geometric_edges(
        render.depth, cam_w.K, RenderEdgeConfig(include_borders=config.include_borders)
    )
    pedges = photo_edges(photo_w)
    mode = config.select_model
    al = _align(redges, pedges, config, select=mode == "always")
    first = _measurement(al, scale, camera, "edges" if mode != "always" else f"edges:{al.model}")
    if mode != "fallback" or _passes(first, threshold_px):
        return _edge_path(first, al, cam_w, scale)
    cv = _align(redges, pedges, config, select=True)
    if not cv.success:
        return _edge_path(first, al, cam_w, scale)
    chosen = _measurement(cv, scale, camera, f"edges:{cv.model}")
    return _edge_path(chosen, al if al.success else cv, cam_w, scale)


def _align(redges: Any, pedges: Any, config: EdgeConfig, select: bool) -> Any:
    from pgt_check.geometry.edges import EdgeAlignConfig, align_edges

    return align_edges(
        redges,
        pedges,
        EdgeAlignConfig(
            model=config.model,
            tile_grid=config.tile_grid,
            decision=config.decision,
            alpha=config.alpha,
            select_model=select,
        ),
    )


#: refusals a different motion model can change (the support and the p-value are measured
#: after the refinement; the edge counts, the overlap and the shift search's ambiguity are not)
_REFIT_CAN_CHANGE = ("low_support", "not_significant", "ill_conditioned_homography")


def _passes(m: PathMeasurement, threshold_px: float | None) -> bool:
    """Whether the cross-validated model has nothing to add: accepted and (with a threshold)
    within it, or refused for a reason no other model changes."""
    if m.reason:
        return m.reason not in _REFIT_CAN_CHANGE
    if m.corner_error_px is None:
        return False
    return threshold_px is None or m.corner_error_px <= threshold_px


def _measurement(al: Any, scale: tuple[float, float], camera: Camera, method: str
                 ) -> PathMeasurement:
    """The stored result of one alignment (homography in original pixels)."""
    from pgt_check.geometry.homography import corner_error, corner_shift_and_zoom, scale_homography

    h = err = dx = dy = zoom = None
    if al.success and al.photo_from_render is not None:
        h_orig = scale_homography(al.photo_from_render, *scale)
        err = corner_error(h_orig, camera.width, camera.height)
        dx, dy, zoom = corner_shift_and_zoom(h_orig, camera.width, camera.height)
        h = tuple(tuple(map(float, r)) for r in h_orig)
    n = int(al.n_edges)
    support = float(al.support) if np.isfinite(al.support) else 0.0
    return PathMeasurement(
        kind="edges",
        method=method,
        evidence=Evidence.ABSOLUTE,
        n_kpts_render=n,
        n_kpts_photo=int(al.n_photo_edges),
        n_matches=n,
        n_inliers=int(round(support * n)),
        inlier_ratio=support,
        reason="" if al.success else al.reason.value,
        photo_from_render=h,
        corner_error_px=err,
        shift_dx_px=dx,
        shift_dy_px=dy,
        zoom=zoom,
    )


def _edge_path(m: PathMeasurement, points_from: Any, cam_w: Camera, scale: tuple[float, float]
               ) -> EdgePath:
    """The path result ``m`` with the matched points of the alignment ``points_from``."""
    mt = points_from.matches
    if not points_from.success or mt is None:
        empty = np.zeros((0, 2))
        return EdgePath(m, empty, empty, np.zeros(0), cam_w, scale)
    return EdgePath(m, mt.render_points, mt.photo_points, mt.depth, cam_w, scale)


def edge_extra(path: EdgePath) -> list[tuple[np.ndarray, np.ndarray, str]]:
    """The matched edge points as the ``extra`` evidence source of
    ``measure.paths.absolute_evidence`` (at most ``MAX_EVIDENCE_POINTS``)."""
    return [(*edge_evidence(path, MAX_EVIDENCE_POINTS), "edges")]


def edge_evidence(path: EdgePath, max_points: int) -> tuple[np.ndarray, np.ndarray]:
    """(pts2d (N, 2) original photo px, pts_cam (N, 3)) from the matched edge points."""
    cam_w, scale = path.cam_w, path.scale
    ok = np.isfinite(path.depth) & (path.depth > 0)
    rp, pp, z = path.render_points[ok], path.photo_points[ok], path.depth[ok]
    if len(rp) > max_points:
        keep = np.linspace(0, len(rp) - 1, max_points).round().astype(int)
        rp, pp, z = rp[keep], pp[keep], z[keep]
    fx, fy = cam_w.focal
    cx, cy = cam_w.principal_point
    pts_cam = np.stack([(rp[:, 0] - cx) / fx * z, (rp[:, 1] - cy) / fy * z, z], axis=1)
    pts2d = (pp + 0.5) / np.asarray(scale) - 0.5
    return pts2d, pts_cam


def edges_lead(config: MeasuringConfig, w: Working) -> bool:
    """The edge path runs first: a render without colours (the raw path matches shading,
    which on the shared colourless meshes never aligned: 0 homographies in 300 frames),
    the edge path on, and the enhancement not forced."""
    return (
        w.render.shading == "shaded"
        and config.edges.lead_on_shaded
        and config.edges.mode != "never"
        and config.enhance.mode != "always"
    )


def edges_only(
    m: FrameMeasurement, w: Working, edges: EdgePath, threshold: float, enhance_mode: str
) -> FrameMeasurement:
    """The measurement of a frame that the leading edge path decides clearly: raw and
    enhanced paths left out (``enhance_why`` edges_decisive, detail ``raw_left_out``)."""
    return replace_measurement(
        m,
        evidence=absolute_evidence(
            [], w.render.depth, w.cam_w, w.scale, extra=edge_extra(edges)
        ),
        edges=edges.measurement,
        enhance_why=EnhanceWhy.EDGES_DECISIVE,
        enhance_why_detail="raw_left_out",
        verdict_path="edges",
        auto_threshold_px=threshold if enhance_mode == "auto" else None,
    )


def edge_path(
    config: MeasuringConfig, renderer: Any, w: Working, raw: PathResult | None,
    threshold: float, clock: Clock,
) -> EdgePath | None:
    """The geometric-edge path, where the config asks for it (auto: raw not decisive; with
    ``raw`` None it runs before the raw path)."""
    e = config.edges
    if e.mode == "never":
        return None
    if e.mode == "auto" and raw is not None:
        decisive = (
            raw.success
            and raw.n_inliers >= config.enhance.auto_min_inliers
            and raw.corner_error_px is not None  # set where it succeeded
            and abs(raw.corner_error_px - threshold) > config.enhance.auto_margin * threshold
        )
        if decisive:
            return None
    render, photo, cam, scale = _edge_images(config, renderer, w, clock)
    t = time.perf_counter()
    out = measure_edges(render, photo, cam, scale, w.camera, e, threshold)
    clock.add("edges", time.perf_counter() - t)
    return out


def _edge_images(
    config: MeasuringConfig, renderer: Any, w: Working, clock: Clock
) -> tuple[Any, np.ndarray, Camera, tuple[float, float]]:
    """(render, photo, working camera, scale) of the edge path: the matching ones, or a
    finer render and photo where ``edges.resize_max`` is larger than the matching size."""
    from pgt_check.io.images import resize_image
    from pgt_check.io.photo import working_scale

    size = working_scale(w.camera.width, w.camera.height, config.edges.resize_max)
    if size[0] <= w.size[0]:
        return w.render, w.photo, w.cam_w, w.scale
    t = time.perf_counter()
    scale = (size[0] / w.camera.width, size[1] / w.camera.height)
    cam = w.camera.scaled(*scale)
    photo = resize_image(w.original, size)
    render = renderer.render(cam, w.world_from_cam)
    clock.add("render", time.perf_counter() - t)
    return render, photo, cam, scale
