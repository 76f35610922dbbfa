"""The geometric-edge path of one frame: the render's silhouettes and creases (from its depth,
never its shading) aligned with the photo's edges (``pgt_check.geometry.edges``).

It is absolute evidence (it depends only on the mesh and this frame's pose) and needs no
texture, so it verifies frames of colourless or textureless meshes where feature matching finds
nothing, and it adds 2D-3D evidence to the run-level checks.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pgt_check.config import EdgeConfig
from pgt_check.enhance.base import Evidence
from pgt_check.measure.record import PathMeasurement
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
) -> EdgePath:
    """Align the render's geometric edges with the photo's (both at working size)."""
    from pgt_check.geometry.edges import (
        EdgeAlignConfig,
        RenderEdgeConfig,
        align_edges,
        geometric_edges,
        photo_edges,
    )
    from pgt_check.geometry.homography import corner_error, corner_shift_and_zoom, scale_homography

    redges = geometric_edges(
        render.depth, cam_w.K, RenderEdgeConfig(include_borders=config.include_borders)
    )
    pedges = photo_edges(photo_w)
    al = align_edges(
        redges,
        pedges,
        EdgeAlignConfig(
            model=config.model,
            tile_grid=config.tile_grid,
            decision=config.decision,
            alpha=config.alpha,
            select_model=config.select_model,
        ),
    )
    h = err = dx = dy = zoom = None
    if al.success and al.photo_from_render is not None:
        h_orig = scale_homography(al.photo_from_render, *scale)
        err = corner_error(h_orig, camera.width, camera.height)
        dx, dy, zoom = corner_shift_and_zoom(h_orig, camera.width, camera.height)
        h = tuple(tuple(map(float, r)) for r in h_orig)
    n = int(al.n_edges)
    support = float(al.support) if np.isfinite(al.support) else 0.0
    m = PathMeasurement(
        kind="edges",
        method="edges",
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
    mt = al.matches
    if not al.success:
        empty = np.zeros((0, 2))
        return EdgePath(m, empty, empty, np.zeros(0), cam_w, scale)
    return EdgePath(m, mt.render_points, mt.photo_points, mt.depth, cam_w, scale)


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
