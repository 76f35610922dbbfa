"""Geometric edges of a render from its depth: occlusions, mesh borders and creases."""

from __future__ import annotations

import logging
import math

import numpy as np

from pgt_check.geometry.edges.config import (
    KIND_BORDER,
    KIND_CREASE,
    KIND_OCCLUSION,
    RenderEdgeConfig,
)
from pgt_check.geometry.edges.results import RenderEdges
from pgt_check.types import check_shape

logger = logging.getLogger(__name__)


def _structure_orientation(points: np.ndarray, width: int, height: int) -> np.ndarray:
    """(N, 2) unit normals of a thin edge set from the structure tensor of its rasterisation."""
    import cv2

    xi = np.clip(np.floor(points[:, 0] + 0.5).astype(np.int64), 0, width - 1)
    yi = np.clip(np.floor(points[:, 1] + 0.5).astype(np.int64), 0, height - 1)
    img: np.ndarray = np.zeros((height, width), dtype=np.float32)
    img[yi, xi] = 1.0
    img = cv2.GaussianBlur(img, (0, 0), 1.0)
    gx = cv2.Sobel(img, cv2.CV_32F, 1, 0, ksize=3)
    gy = cv2.Sobel(img, cv2.CV_32F, 0, 1, ksize=3)
    jxx = cv2.GaussianBlur(gx * gx, (0, 0), 1.5)
    jxy = cv2.GaussianBlur(gx * gy, (0, 0), 1.5)
    jyy = cv2.GaussianBlur(gy * gy, (0, 0), 1.5)
    theta = 0.5 * np.arctan2(2.0 * jxy[yi, xi], jxx[yi, xi] - jyy[yi, xi])
    return np.stack([np.cos(theta), np.sin(theta)], axis=1).astype(np.float64)


def _occlusion_pairs(inv: np.ndarray, valid: np.ndarray, rel: float, axis: int):
    """Occlusion and border pairs of neighbours along ``axis`` (inverse depth, 0 = no surface).

    Returns (occluding, border) bool masks for the pairs (i, i+1) along ``axis``: (H, W-1) for
    axis 1, (H-1, W) for axis 0. A pair is an occlusion when both pixels are covered and planar
    extrapolation of inverse depth (exact on planes) from either side mis-predicts the other
    side by more than ``rel`` x the near inverse depth (the better of the two sides counts; an
    uncovered outer neighbour extrapolates badly and so defers to the other side).
    """
    pad = ((0, 0), (1, 1)) if axis == 1 else ((1, 1), (0, 0))
    p = np.pad(inv, pad)

    def sl(start: int, stop: int | None) -> np.ndarray:
        return p[:, start:stop] if axis == 1 else p[start:stop, :]

    a_prev, a, b, b_next = sl(0, -3), sl(1, -2), sl(2, -1), sl(3, None)
    jump = np.abs(a - b)
    near = np.maximum(a, b)
    err = np.minimum(np.abs(b - 2 * a + a_prev), np.abs(a - 2 * b + b_next))
    va = valid[:, :-1] if axis == 1 else valid[:-1, :]
    vb = valid[:, 1:] if axis == 1 else valid[1:, :]
    thr = rel * near
    occluding = va & vb & (err > thr) & (jump > 0.5 * thr)
    return occluding, va ^ vb


def _pair_points(mask: np.ndarray, axis: int) -> tuple[np.ndarray, tuple, tuple]:
    """Midpoints (x, y) of the pairs in ``mask`` and the (rows, cols) of both pixels."""
    r, c = np.nonzero(mask)
    if axis == 1:
        pts = np.stack([c + 0.5, r.astype(np.float64)], axis=1)
        return pts, (r, c), (r, c + 1)
    pts = np.stack([c.astype(np.float64), r + 0.5], axis=1)
    return pts, (r, c), (r + 1, c)


def _normals(
    xyz: tuple[np.ndarray, np.ndarray, np.ndarray], usable: np.ndarray, k: int
) -> tuple[tuple[np.ndarray, np.ndarray, np.ndarray], np.ndarray]:
    """Unit normals (three (H, W) float32 components) from central differences with baseline
    ``k`` of the back-projected points, and where they are valid."""
    h, w = usable.shape
    if h <= 2 * k or w <= 2 * k:
        zero = np.zeros((h, w), dtype=np.float32)
        return (zero, zero, zero), np.zeros((h, w), dtype=bool)
    dx = [c[k:-k, 2 * k :] - c[k:-k, : -2 * k] for c in xyz]
    dy = [c[2 * k :, k:-k] - c[: -2 * k, k:-k] for c in xyz]
    c0 = dx[1] * dy[2] - dx[2] * dy[1]
    c1 = dx[2] * dy[0] - dx[0] * dy[2]
    c2 = dx[0] * dy[1] - dx[1] * dy[0]
    norm = np.sqrt(c0 * c0 + c1 * c1 + c2 * c2)
    inner = (
        usable[k:-k, k:-k]
        & usable[k:-k, 2 * k :]
        & usable[k:-k, : -2 * k]
        & usable[2 * k :, k:-k]
        & usable[: -2 * k, k:-k]
        & (norm > 0)
    )
    inv_norm = np.where(inner, 1.0 / np.where(inner, norm, 1.0), 0.0).astype(np.float32)
    out = []
    for c in (c0, c1, c2):
        full = np.zeros((h, w), dtype=np.float32)
        full[k:-k, k:-k] = c * inv_norm
        out.append(full)
    ok = np.zeros((h, w), dtype=bool)
    ok[k:-k, k:-k] = inner
    return (out[0], out[1], out[2]), ok


def _crease_pixels(
    n: tuple[np.ndarray, np.ndarray, np.ndarray], ok: np.ndarray, cos_max: float, k: int
) -> tuple[np.ndarray, np.ndarray]:
    """(rows, cols) of crease pixels: the normals k px before and after a pixel differ by more
    than the threshold; non-maximum suppressed along the direction of the larger change."""
    h, w = ok.shape
    sh = np.zeros((h, w), dtype=np.float32)  # 1 - cos across the pixel, horizontally
    sv = np.zeros((h, w), dtype=np.float32)  # and vertically
    if w > 2 * k:
        a, b = slice(None, -2 * k), slice(2 * k, None)
        d = n[0][:, a] * n[0][:, b] + n[1][:, a] * n[1][:, b] + n[2][:, a] * n[2][:, b]
        sh[:, k:-k] = np.where(ok[:, a] & ok[:, b], 1.0 - d, 0.0)
    if h > 2 * k:
        a, b = slice(None, -2 * k), slice(2 * k, None)
        d = n[0][a] * n[0][b] + n[1][a] * n[1][b] + n[2][a] * n[2][b]
        sv[k:-k, :] = np.where(ok[a] & ok[b], 1.0 - d, 0.0)
    s = np.maximum(sh, sv)
    cand = s > (1.0 - cos_max)
    pad = np.pad(s, 1)
    horizontal = sh >= sv
    keep_h = horizontal & (s >= pad[1:-1, :-2]) & (s > pad[1:-1, 2:])
    keep_v = ~horizontal & (s >= pad[:-2, 1:-1]) & (s > pad[2:, 1:-1])
    rows, cols = np.nonzero(cand & (keep_h | keep_v))
    return rows, cols


def _pair_edges(
    z: np.ndarray, inv: np.ndarray, valid: np.ndarray, config: RenderEdgeConfig
) -> tuple[list, list, list, np.ndarray]:
    """Occlusion and border points (lists of points, depths, kinds per mask) and the pixels of
    any occlusion or border pair (also of borders that are not kept)."""
    h, w = z.shape
    pts, dep, kinds = [], [], []
    occ_near = np.zeros((h, w), dtype=bool)  # pixels of an occlusion or border pair
    for axis in (1, 0):
        occ, border = _occlusion_pairs(inv, valid, config.depth_jump_rel, axis)
        for mask, kind in ((occ, KIND_OCCLUSION), (border, KIND_BORDER)):
            p, (ra, ca), (rb, cb) = _pair_points(mask, axis)
            occ_near[ra, ca] = True
            occ_near[rb, cb] = True
            if kind == KIND_BORDER and not config.include_borders:
                continue
            za, zb = z[ra, ca], z[rb, cb]
            # occlusion: the near (occluding) surface; border: the covered side
            d = np.minimum(za, zb) if kind == KIND_OCCLUSION else np.maximum(za, zb)
            pts.append(p)
            dep.append(d.astype(np.float64))
            kinds.append(np.full(len(p), kind, dtype=np.uint8))
    return pts, dep, kinds, occ_near


def _crease_edges(
    z: np.ndarray, usable: np.ndarray, camera_K: np.ndarray, config: RenderEdgeConfig
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Crease points (x, y), their depths and kinds; ``usable``: covered pixels off any
    occlusion or border pair."""
    import cv2

    h, w = z.shape
    k = max(1, int(config.normal_step_px))
    kinv = np.linalg.inv(camera_K)
    xs = np.arange(w, dtype=np.float64)
    ys = np.arange(h, dtype=np.float64)[:, None]
    rx = (kinv[0, 0] * xs + kinv[0, 1] * ys + kinv[0, 2]).astype(np.float32)
    ry = (kinv[1, 0] * xs + kinv[1, 1] * ys + kinv[1, 2]).astype(np.float32)
    n, ok = _normals((rx * z, ry * z, z), usable, k)
    rows, cols = _crease_pixels(n, ok, math.cos(math.radians(config.crease_angle_deg)), k)
    margin = max(0, int(config.crease_margin_px))
    if margin and len(rows):
        kern = np.ones((2 * margin + 1, 2 * margin + 1), np.uint8)
        blocked = cv2.dilate((~usable).view(np.uint8), kern) > 0
        keep = ~blocked[rows, cols]
        rows, cols = rows[keep], cols[keep]
    return (
        np.stack([cols, rows], axis=1).astype(np.float64),
        z[rows, cols].astype(np.float64),
        np.full(len(rows), KIND_CREASE, dtype=np.uint8),
    )


def _first_per_pixel(points: np.ndarray, width: int) -> np.ndarray:
    """Indices (ascending) of the first point of each rounded pixel position."""
    key = np.floor(points[:, 1] + 0.5).astype(np.int64) * (width + 1) + np.floor(
        points[:, 0] + 0.5
    ).astype(np.int64)
    _, first = np.unique(key, return_index=True)
    first.sort()
    return first


def geometric_edges(
    depth: np.ndarray, camera_K: np.ndarray, config: RenderEdgeConfig = RenderEdgeConfig()
) -> RenderEdges:
    """Silhouettes, mesh borders and creases of a render, from its depth only.

    depth: (H, W) metric z (0 or non-finite = no surface); camera_K: (3, 3) intrinsics of the
    render (OpenCV pixel convention). Occlusion edges: inverse-depth discontinuities (planar
    extrapolation from both sides fails by ``depth_jump_rel``); borders: covered / uncovered
    pairs; creases: angle between back-projected normals across a pixel above
    ``crease_angle_deg``, non-maximum suppressed to one pixel. The shaded colour is not used.
    Points are unique per pixel (rounded position); occlusions and borders win over creases.
    """
    depth = np.asarray(depth)
    camera_K = np.asarray(camera_K, dtype=np.float64)
    if depth.ndim != 2:
        raise ValueError(f"depth: expected shape (H, W), got {depth.shape}")
    check_shape("camera_K", camera_K, (3, 3))
    h, w = depth.shape
    z = depth.astype(np.float32, copy=True)
    valid = np.isfinite(z) & (z > 0)
    z[~valid] = 0.0
    inv = np.zeros_like(z)
    np.divide(1.0, z, out=inv, where=valid)

    pts, dep, kinds, occ_near = _pair_edges(z, inv, valid, config)
    if config.include_creases and config.crease_angle_deg < 180:
        crease = _crease_edges(z, valid & ~occ_near, camera_K, config)
        for lst, arr in zip((pts, dep, kinds), crease, strict=True):
            lst.append(arr)

    points = np.concatenate(pts) if pts else np.zeros((0, 2))
    depths = np.concatenate(dep) if dep else np.zeros(0)
    kind = np.concatenate(kinds) if kinds else np.zeros(0, dtype=np.uint8)
    # one point per pixel (horizontal and vertical pairs of a staircase round to distinct pixels
    # mostly; exact duplicates of the rounded position are dropped, occlusions first)
    if len(points):
        first = _first_per_pixel(points, w)
        points, depths, kind = points[first], depths[first], kind[first]
    n_detected = len(points)
    normals = (
        _structure_orientation(points, w, h) if len(points) else np.zeros((0, 2), dtype=np.float64)
    )
    if config.max_points is not None and n_detected > config.max_points:
        rng = np.random.default_rng(config.seed)
        sel = np.sort(rng.choice(n_detected, size=config.max_points, replace=False))
        points, depths, kind, normals = points[sel], depths[sel], kind[sel], normals[sel]
    logger.debug("render edges: %d detected, %d kept", n_detected, len(points))
    return RenderEdges(points, normals, depths, kind, w, h, n_detected, camera_K.copy())
