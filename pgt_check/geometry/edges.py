"""Geometry-edge evidence: align the render's geometric edges with the photo's edges.

On textureless scenes feature matching finds nothing, yet silhouettes and creases of the mesh
line up with the photo's edges when the pose is right. This module estimates the 2D motion
``photo_from_render`` (3x3, render pixels -> photo pixels, OpenCV pixel convention) that aligns
them, and scores it like the feature path (corner error, support, ambiguity).

```python
re = geometric_edges(render.depth, camera.K)        # silhouettes + creases, from depth only
pe = photo_edges(photo_rgb)                          # Canny + orientation + distance transforms
al = align_edges(re, pe)                             # EdgeAlignment(success, reason, ...)
al.corner_error, al.support, al.ambiguous, al.matches.render_points, al.matches.depth
```

Steps of ``align_edges``:

(a) exhaustive search over integer 2D shifts (+-``search_radius`` x image diagonal, coarse grid
    of ~0.5 % of the diagonal, then 1 px) of an oriented, truncated chamfer score: the mean of
    ``1 - min(d, tau) / tau`` over the render edge points, d = distance to the nearest photo edge
    whose orientation is within one bin (22.5 deg) of the point's. The best score farther than
    3 tau from the best one (a second peak: repeated structure; or a ridge: parallel edges only)
    gives the ambiguity, normalised by the median score of all shifts.
(b) refinement from two starts, the best shift as a translation and as the camera rotation
    that produces it (``rotation_homography``, which carries the keystone of a real rotation):
    re-search of the shift at a narrow truncation, then point-to-line iterative closest edge
    (oriented correspondences from per-bin distance transforms with labels, Tukey IRLS,
    Levenberg damping) from shift through similarity and affine to ``model``, then ``model``
    with the Tukey scale annealed from tau to ``final_scale`` x tau. Only the start with the
    better narrow score is refined.

Pure numpy / OpenCV / scipy.
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass, field
from enum import Enum
from functools import cached_property

import numpy as np

from pgt_check.geometry.homography import check_homography, corner_error, image_corners
from pgt_check.types import check_shape

logger = logging.getLogger(__name__)

#: kinds of render edge points (``RenderEdges.kind``)
KIND_OCCLUSION = 0  # depth discontinuity between two surfaces
KIND_BORDER = 1  # mesh / background border
KIND_CREASE = 2  # normal discontinuity on one surface

MODELS = ("shift", "similarity", "affine", "homography")
_N_PARAMS = {"shift": 2, "similarity": 4, "affine": 6, "homography": 8}


class EdgeReason(str, Enum):
    """Why an edge alignment is not usable (machine-readable, closed set)."""

    TOO_FEW_EDGES = "too_few_edges"
    TOO_FEW_PHOTO_EDGES = "too_few_photo_edges"
    NO_OVERLAP = "no_overlap"
    LOW_SUPPORT = "low_support"
    AMBIGUOUS = "ambiguous"
    ILL_CONDITIONED = "ill_conditioned_homography"


# --------------------------------------------------------------------------------------------
# configs and results


@dataclass(frozen=True)
class RenderEdgeConfig:
    """Settings of ``geometric_edges`` (pixels of the render)."""

    #: occlusion edge: inverse depth mis-predicted (by planar extrapolation from both sides) by
    #: more than this fraction of the near inverse depth
    depth_jump_rel: float = 0.04
    #: crease: angle between the normals on both sides of a pixel above this (degrees)
    crease_angle_deg: float = 28.0
    #: baseline (px) of the finite differences for normals; 2 smooths faceted / noisy meshes
    normal_step_px: int = 2
    #: no creases this close (px) to an occlusion edge or the background (normals unreliable)
    crease_margin_px: int = 2
    include_borders: bool = True
    include_creases: bool = True
    #: keep at most this many points (seeded random subsample); None = all
    max_points: int | None = 4000
    seed: int = 0


@dataclass(frozen=True)
class PhotoEdgeConfig:
    """Settings of ``photo_edges``."""

    blur_sigma: float = 1.0
    #: Canny high threshold = max(this percentile of the gradient magnitude,
    #: ``median_factor`` x median, ``min_gradient`` (grey levels per pixel))
    high_percentile: float = 90.0
    median_factor: float = 3.0
    min_gradient: float = 6.0
    low_ratio: float = 0.4
    #: orientation bins over [0, pi); a render edge matches photo edges of its bin +- 1
    n_bins: int = 8


@dataclass(frozen=True)
class EdgeAlignConfig:
    """Settings of ``align_edges`` (pixels of the working images)."""

    #: chamfer truncation / inlier distance (px); None = 0.0075 x image diagonal, at least 3
    tau_px: float | None = None
    #: shift search range as a fraction of the image diagonal
    search_radius: float = 0.1
    #: coarse shift grid step (px); None = 0.005 x diagonal, at least 2
    coarse_step_px: float | None = None
    coarse_points: int = 500
    fine_points: int = 2000
    refine_points: int = 2000
    #: a shift must keep at least this share of the render edges inside the photo
    min_inside: float = 0.5
    model: str = "homography"
    #: refinement iterations in all (split over the stages shift -> ... -> model)
    iterations: int = 30
    #: a stage stops when an update moves no image corner by more than this (px)
    converged_px: float = 0.02
    #: Levenberg damping, relative to the mean diagonal of the normal equations
    damping: float = 1e-3
    #: Tukey scale of the last refinement stage: max(min_scale_px, final_scale x tau)
    final_scale: float = 0.35
    min_scale_px: float = 1.5
    #: before refining, re-search the shift within +- this (px) at the narrow final scale
    polish_radius_px: int = 3
    #: best shift farther than ``ambiguity_separation`` x tau from the best (a second peak or a
    #: ridge of parallel edges) whose score above the median shift score is at least this share
    #: of the best's -> ambiguous
    ambiguity_ratio: float = 0.85
    ambiguity_separation: float = 3.0
    min_edges: int = 50
    min_photo_edges: int = 50
    min_support: float = 0.3


@dataclass(frozen=True, eq=False)
class RenderEdges:
    """Geometric edge points of a render.

    points: (N, 2) float64 pixel coordinates (x, y) on the edge (midpoints between the two pixels
    of an occlusion / border pair; pixel centres for creases). normals: (N, 2) float64 unit edge
    normal (direction across the edge, sign arbitrary). depth: (N,) float64 metric depth of the
    surface the edge belongs to (the near side for occlusions). kind: (N,) uint8, KIND_*.
    n_detected: number of points before subsampling. camera_K: the render's intrinsics (lets
    ``align_edges`` start from the camera rotation that explains the best shift).
    """

    points: np.ndarray
    normals: np.ndarray
    depth: np.ndarray
    kind: np.ndarray
    width: int
    height: int
    n_detected: int
    camera_K: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.points)

    @property
    def angles(self) -> np.ndarray:
        """(N,) normal orientation in [0, pi)."""
        return np.mod(np.arctan2(self.normals[:, 1], self.normals[:, 0]), np.pi)


@dataclass(frozen=True, eq=False)
class PhotoEdges:
    """Edges of a photo and the maps for (oriented) chamfer matching.

    magnitude: (H, W) float32 gradient magnitude (grey levels 0-255 per pixel, Sobel / 8);
    grad_x, grad_y: (H, W) float32 Sobel derivatives of the blurred grey image (x 8);
    ``orientation`` (computed on first use): gradient (edge normal) direction in [0, pi).
    edges: (H, W) bool Canny edges.
    points: (E, 2) float64 sub-pixel edge positions (x, y); normals: (E, 2) unit edge normals;
    pixels: (E, 2) int32 (x, y) of the Canny pixel; bins: (E,) orientation bin.
    oriented_dist: (B, H, W) float32 distance to the nearest edge whose orientation bin is within
    +-1 of b (inf if there is none); oriented_labels: (B, H, W) int32 OpenCV label of that edge
    pixel, resolved by ``compatible_nearest`` / ``oriented_nearest``; label_edges: per bin, edge
    index of each label - 1. ``dist`` / ``nearest`` (unoriented) are computed on first use.
    """

    magnitude: np.ndarray
    grad_x: np.ndarray
    grad_y: np.ndarray
    edges: np.ndarray
    points: np.ndarray
    normals: np.ndarray
    pixels: np.ndarray
    bins: np.ndarray
    oriented_dist: np.ndarray
    oriented_labels: np.ndarray
    label_edges: tuple[np.ndarray, ...]
    thresholds: tuple[float, float]

    @property
    def width(self) -> int:
        return int(self.edges.shape[1])

    @property
    def height(self) -> int:
        return int(self.edges.shape[0])

    @property
    def n_bins(self) -> int:
        return int(self.oriented_dist.shape[0])

    def __len__(self) -> int:
        return len(self.points)

    @cached_property
    def orientation(self) -> np.ndarray:
        """(H, W) float32 gradient (edge normal) direction in [0, pi)."""
        return np.mod(np.arctan2(self.grad_y, self.grad_x), np.pi).astype(np.float32)

    @cached_property
    def _label_lut(self) -> tuple[np.ndarray, np.ndarray]:
        sizes = [len(x) for x in self.label_edges]
        offsets = np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64)
        lut = np.concatenate([*self.label_edges, np.zeros(0, np.int32)]).astype(np.int32)
        return lut, offsets

    def compatible_nearest(
        self, bins: np.ndarray, x: np.ndarray, y: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """(distance, edge index) of the nearest edge compatible with orientation ``bins`` at
        integer pixels (x, y) (all (N,), inside the image); index -1 where there is none."""
        d = self.oriented_dist[bins, y, x]
        lab = self.oriented_labels[bins, y, x].astype(np.int64)
        lut, offsets = self._label_lut
        ok = (lab > 0) & np.isfinite(d)
        e = np.full(len(d), -1, dtype=np.int64)
        e[ok] = lut[offsets[bins[ok]] + lab[ok] - 1]
        return d, e

    @cached_property
    def oriented_nearest(self) -> np.ndarray:
        """(B, H, W) int32 index into ``points`` of the nearest compatible edge (-1: none)."""
        out = np.full(self.oriented_labels.shape, -1, dtype=np.int32)
        for b, edges_b in enumerate(self.label_edges):
            if len(edges_b):
                lab = self.oriented_labels[b]
                out[b] = np.where(lab > 0, edges_b[np.maximum(lab, 1) - 1], -1)
        return out

    @cached_property
    def _unoriented(self) -> tuple[np.ndarray, np.ndarray]:
        dist, labels, order = _distance_with_labels(self.edges)
        if not len(order):
            return dist, np.full(dist.shape, -1, dtype=np.int32)
        edge_of = np.searchsorted(_row_major_index(self.pixels, self.width), order)
        return dist, np.where(labels > 0, edge_of[np.maximum(labels, 1) - 1], -1).astype(np.int32)

    @property
    def dist(self) -> np.ndarray:
        """(H, W) float32 distance (px) to the nearest edge pixel, any orientation."""
        return self._unoriented[0]

    @property
    def nearest(self) -> np.ndarray:
        """(H, W) int32 index into ``points`` of the nearest edge (-1 if there is none)."""
        return self._unoriented[1]


@dataclass(frozen=True, eq=False)
class EdgeMatches:
    """Render edge points matched to photo edges after alignment (for 2D-3D evidence).

    render_points: (M, 2) render pixels; depth: (M,) their render depth (lift with K^-1);
    photo_points: (M, 2) the aligned point ``photo_from_render @ p`` moved onto the matched
    photo edge line (foot of the perpendicular): the photo observation, exact across the edge
    and only as good as the homography along it; photo_normals: (M, 2) the photo edge normal, for
    point-to-line residuals; residuals: (M,) signed point-to-line distance (px) before the move.
    """

    render_points: np.ndarray
    photo_points: np.ndarray
    photo_normals: np.ndarray
    depth: np.ndarray
    residuals: np.ndarray

    def __len__(self) -> int:
        return len(self.render_points)


def _no_matches() -> EdgeMatches:
    z2 = np.zeros((0, 2))
    return EdgeMatches(z2, z2.copy(), z2.copy(), np.zeros(0), np.zeros(0))


@dataclass(frozen=True, eq=False)
class EdgeAlignment:
    """Result of ``align_edges``.

    ``photo_from_render`` / ``corner_error`` are the measured alignment whenever one was computed
    (also when ``success`` is False for "ambiguous" or "low_support", for diagnostics); they are
    None / inf when nothing could be computed. Callers must check ``success``.
    shift: (dx, dy) best integer-grid shift of the search; second_shift / second_score: the
    separated runner-up (None if there is none); baseline_score: median score over all searched
    shifts; ambiguity: (second_score - baseline) / (score - baseline), 0 if there is no runner-up.
    support: share of render edge points within tau of a compatible photo edge after alignment;
    support_identity: the same at the identity. residual_px: median |point-to-line| distance of
    the matched points. timings: seconds per step.
    """

    success: bool
    reason: EdgeReason | None
    photo_from_render: np.ndarray | None
    corner_error: float
    support: float
    support_identity: float
    residual_px: float
    n_edges: int
    n_photo_edges: int
    score: float
    baseline_score: float
    shift: tuple[float, float] | None
    second_shift: tuple[float, float] | None
    second_score: float
    ambiguity: float
    ambiguous: bool
    tau_px: float
    model: str
    matches: EdgeMatches = field(default_factory=_no_matches)
    timings: dict[str, float] = field(default_factory=dict)


# --------------------------------------------------------------------------------------------
# render edges


def _structure_orientation(points: np.ndarray, width: int, height: int) -> np.ndarray:
    """(N, 2) unit normals of a thin edge set from the structure tensor of its rasterisation."""
    import cv2

    xi = np.clip(np.floor(points[:, 0] + 0.5).astype(np.int64), 0, width - 1)
    yi = np.clip(np.floor(points[:, 1] + 0.5).astype(np.int64), 0, height - 1)
    img = np.zeros((height, width), dtype=np.float32)
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
    return np.nonzero(cand & (keep_h | keep_v))


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
    import cv2

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

    if config.include_creases and config.crease_angle_deg < 180:
        k = max(1, int(config.normal_step_px))
        kinv = np.linalg.inv(camera_K)
        xs = np.arange(w, dtype=np.float64)
        ys = np.arange(h, dtype=np.float64)[:, None]
        rx = (kinv[0, 0] * xs + kinv[0, 1] * ys + kinv[0, 2]).astype(np.float32)
        ry = (kinv[1, 0] * xs + kinv[1, 1] * ys + kinv[1, 2]).astype(np.float32)
        usable = valid & ~occ_near
        n, ok = _normals((rx * z, ry * z, z), usable, k)
        rows, cols = _crease_pixels(n, ok, math.cos(math.radians(config.crease_angle_deg)), k)
        margin = max(0, int(config.crease_margin_px))
        if margin and len(rows):
            kern = np.ones((2 * margin + 1, 2 * margin + 1), np.uint8)
            blocked = cv2.dilate((~usable).view(np.uint8), kern) > 0
            keep = ~blocked[rows, cols]
            rows, cols = rows[keep], cols[keep]
        pts.append(np.stack([cols, rows], axis=1).astype(np.float64))
        dep.append(z[rows, cols].astype(np.float64))
        kinds.append(np.full(len(rows), KIND_CREASE, dtype=np.uint8))

    points = np.concatenate(pts) if pts else np.zeros((0, 2))
    depths = np.concatenate(dep) if dep else np.zeros(0)
    kind = np.concatenate(kinds) if kinds else np.zeros(0, dtype=np.uint8)
    # one point per pixel (horizontal and vertical pairs of a staircase round to distinct pixels
    # mostly; exact duplicates of the rounded position are dropped, occlusions first)
    if len(points):
        key = np.floor(points[:, 1] + 0.5).astype(np.int64) * (w + 1) + np.floor(
            points[:, 0] + 0.5
        ).astype(np.int64)
        _, first = np.unique(key, return_index=True)
        first.sort()
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


# --------------------------------------------------------------------------------------------
# photo edges


def _row_major_index(pixels: np.ndarray, width: int) -> np.ndarray:
    return pixels[:, 1].astype(np.int64) * width + pixels[:, 0].astype(np.int64)


def _distance_with_labels(mask: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Distance to the nearest True pixel of ``mask``, its OpenCV label (from 1; 0 = none) and
    the row-major pixel index of each label - 1 (OpenCV numbers the zero pixels row-major)."""
    import cv2

    h, w = mask.shape
    order = np.flatnonzero(mask.ravel())
    if not len(order):
        return np.full((h, w), np.inf, np.float32), np.zeros((h, w), np.int32), order
    src = np.where(mask, 0, 255).astype(np.uint8)
    dist, labels = cv2.distanceTransformWithLabels(
        src, cv2.DIST_L2, 5, labelType=cv2.DIST_LABEL_PIXEL
    )
    return dist, labels, order


def photo_edges(photo_rgb: np.ndarray, config: PhotoEdgeConfig = PhotoEdgeConfig()) -> PhotoEdges:
    """Canny edges of a photo with sub-pixel positions, orientations and chamfer maps.

    photo_rgb: (H, W, 3) float RGB in [0, 1] (or (H, W) grey). Canny thresholds adapt to the
    image: high = max(``high_percentile`` of the gradient magnitude, ``median_factor`` x its
    median, ``min_gradient``), low = ``low_ratio`` x high.
    """
    import cv2

    img = np.asarray(photo_rgb, dtype=np.float32)
    if img.ndim == 3:
        check_shape("photo_rgb", img, (None, None, 3))
        gray = cv2.cvtColor(img, cv2.COLOR_RGB2GRAY)
    elif img.ndim == 2:
        gray = img
    else:
        raise ValueError(f"photo_rgb: expected shape (H, W, 3), got {img.shape}")
    h, w = gray.shape
    gray = gray * 255.0
    if config.blur_sigma > 0:
        gray = cv2.GaussianBlur(gray, (0, 0), config.blur_sigma)
    gx = cv2.Sobel(gray, cv2.CV_32F, 1, 0, ksize=3)
    gy = cv2.Sobel(gray, cv2.CV_32F, 0, 1, ksize=3)
    mag = cv2.magnitude(gx, gy)  # Sobel units (8 x grey levels per pixel)
    per_px = mag / 8.0
    sample = per_px[::2, ::2]  # thresholds from a quarter of the pixels (speed)
    hi = max(
        float(np.percentile(sample, config.high_percentile)),
        config.median_factor * float(np.median(sample)),
        config.min_gradient,
    )
    lo = config.low_ratio * hi
    # OpenCV Canny on given derivatives (int16): keep full range by scaling to fit
    scale = min(1.0, 30000.0 / max(float(mag.max()), 1e-6))
    dx = (gx * scale).astype(np.int16)
    dy = (gy * scale).astype(np.int16)
    edges = cv2.Canny(dx, dy, lo * 8.0 * scale, hi * 8.0 * scale, L2gradient=True) > 0

    rows, cols = np.nonzero(edges)  # row-major order
    pixels = np.stack([cols, rows], axis=1).astype(np.int32)
    th = np.mod(np.arctan2(gy[rows, cols], gx[rows, cols]), np.pi).astype(np.float64)
    normals = np.stack([np.cos(th), np.sin(th)], axis=1)
    # sub-pixel: parabola through the magnitude at -1, 0, +1 along the quantised normal
    q = np.floor(th / (np.pi / 4) + 0.5).astype(np.int64) % 4  # 0: x, 1: diag, 2: y, 3: anti
    steps = np.array([[1, 0], [1, 1], [0, 1], [-1, 1]])[q]
    xp = np.clip(cols + steps[:, 0], 0, w - 1)
    yp = np.clip(rows + steps[:, 1], 0, h - 1)
    xm = np.clip(cols - steps[:, 0], 0, w - 1)
    ym = np.clip(rows - steps[:, 1], 0, h - 1)
    m0 = mag[rows, cols].astype(np.float64)
    mp = mag[yp, xp].astype(np.float64)
    mm = mag[ym, xm].astype(np.float64)
    den = mm - 2 * m0 + mp
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(den < 0, 0.5 * (mm - mp) / den, 0.0)
    t = np.clip(np.nan_to_num(t), -0.5, 0.5)
    points = np.stack([cols + t * steps[:, 0], rows + t * steps[:, 1]], axis=1).astype(np.float64)

    n_bins = int(config.n_bins)
    if n_bins < 3:
        raise ValueError(f"n_bins must be >= 3, got {n_bins}")
    bins = np.floor(th / (np.pi / n_bins) + 0.5).astype(np.int64) % n_bins
    odist = np.empty((n_bins, h, w), dtype=np.float32)
    olab = np.empty((n_bins, h, w), dtype=np.int32)
    bin_map = np.full((h, w), 255, dtype=np.uint8)
    bin_map[rows, cols] = bins
    label_edges = []
    for b in range(n_bins):
        compat = [(b - 1) % n_bins, b, (b + 1) % n_bins]
        lut = np.full(256, 255, dtype=np.uint8)
        lut[compat] = 0
        src = cv2.LUT(bin_map, lut)
        # OpenCV numbers the zero pixels row-major from 1, as ``points`` are ordered
        label_edges.append(np.flatnonzero(np.isin(bins, compat)).astype(np.int32))
        if len(label_edges[-1]):
            odist[b], olab[b] = cv2.distanceTransformWithLabels(
                src, cv2.DIST_L2, 5, labelType=cv2.DIST_LABEL_PIXEL
            )
        else:
            odist[b], olab[b] = np.inf, 0
    logger.debug("photo edges: %d pixels, canny thresholds %.1f / %.1f", len(points), lo, hi)
    return PhotoEdges(
        magnitude=per_px,
        grad_x=gx,
        grad_y=gy,
        edges=edges,
        points=points,
        normals=normals,
        pixels=pixels,
        bins=bins.astype(np.int32),
        oriented_dist=odist,
        oriented_labels=olab,
        label_edges=tuple(label_edges),
        thresholds=(lo, hi),
    )


# --------------------------------------------------------------------------------------------
# alignment


def _bins_of(normals: np.ndarray, n_bins: int) -> np.ndarray:
    ang = np.mod(np.arctan2(normals[:, 1], normals[:, 0]), np.pi)
    return (np.floor(ang / (np.pi / n_bins) + 0.5).astype(np.int64) % n_bins).astype(np.int64)


@dataclass(frozen=True, eq=False)
class _ScoreMaps:
    """Truncated chamfer scores 255 x (1 - min(d, tau) / tau) per orientation bin, as uint8,
    padded by ``pad`` pixels of 0 so that shifted look-ups need no bounds checks."""

    flat: np.ndarray
    pad: int
    width: int
    height: int

    @classmethod
    def build(cls, pe: PhotoEdges, tau: float, pad: int) -> _ScoreMaps:
        import cv2

        b, h, w = pe.oriented_dist.shape
        out = np.zeros((b, h + 2 * pad, w + 2 * pad), dtype=np.uint8)
        for i in range(b):
            d = np.minimum(pe.oriented_dist[i], np.float32(tau))  # inf (no edge) -> tau
            # 255 (1 - d / tau), saturated to uint8
            out[i, pad : pad + h, pad : pad + w] = cv2.convertScaleAbs(
                d, alpha=-255.0 / tau, beta=255.0
            )
        return cls(out.reshape(-1), pad, w, h)

    def scores(
        self, pts: np.ndarray, bins: np.ndarray, shifts: np.ndarray, min_inside: float
    ) -> np.ndarray:
        """Mean score over the points that land inside the photo, for each integer shift (S, 2);
        0 where fewer than ``min_inside`` of the points land inside."""
        w, h, pad = self.width, self.height, self.pad
        wp, hp = w + 2 * pad, h + 2 * pad
        x = np.floor(pts[:, 0] + 0.5).astype(np.int64)
        y = np.floor(pts[:, 1] + 0.5).astype(np.int64)
        sx = np.round(shifts[:, 0]).astype(np.int64)
        sy = np.round(shifts[:, 1]).astype(np.int64)
        if np.any(np.abs(sx) > pad) or np.any(np.abs(sy) > pad):
            raise ValueError("shift beyond the padding of the score maps")
        pidx = (bins * (hp * wp) + (y + pad) * wp + (x + pad)).astype(np.int32)
        soff = (sy * wp + sx).astype(np.int32)
        out = np.empty(len(shifts), dtype=np.float64)
        chunk = max(1, 2_000_000 // max(1, len(pts)))
        for s0 in range(0, len(shifts), chunk):
            idx = soff[s0 : s0 + chunk, None] + pidx[None, :]
            out[s0 : s0 + chunk] = self.flat[idx].sum(axis=1, dtype=np.int64)
        n_in = _count_in_windows(x, y, -sx, w - sx, -sy, h - sy)
        with np.errstate(divide="ignore", invalid="ignore"):
            mean = out / 255.0 / np.maximum(n_in, 1)
        return np.where(n_in >= min_inside * len(pts), mean, 0.0)


def _count_in_windows(
    x: np.ndarray, y: np.ndarray, x0: np.ndarray, x1: np.ndarray, y0: np.ndarray, y1: np.ndarray
) -> np.ndarray:
    """Number of points with x0 <= x < x1 and y0 <= y < y1, per window (all integer arrays):
    a 2D histogram on the window bounds only, integrated."""
    ex = np.unique(np.concatenate([x0, x1]))
    ey = np.unique(np.concatenate([y0, y1]))
    bx = np.searchsorted(ex, x, side="right")  # point counts as "< ex[i]" for i >= bx
    by = np.searchsorted(ey, y, side="right")
    hist = np.bincount(by * (len(ex) + 1) + bx, minlength=(len(ey) + 1) * (len(ex) + 1))
    cum = hist.reshape(len(ey) + 1, len(ex) + 1).cumsum(0).cumsum(1)  # cum[j, i]: y<ey[j], x<ex[i]

    def c(yy: np.ndarray, xx: np.ndarray) -> np.ndarray:
        return cum[np.searchsorted(ey, yy), np.searchsorted(ex, xx)]

    return c(y1, x1) - c(y0, x1) - c(y1, x0) + c(y0, x0)


def _subset(n: int, k: int) -> np.ndarray:
    """Evenly spread indices of at most k out of n (deterministic)."""
    if n <= k:
        return np.arange(n)
    return np.unique(np.linspace(0, n - 1, k).round().astype(np.int64))


def _separated_runner_up(
    grid: np.ndarray, xs: np.ndarray, ys: np.ndarray, best: tuple[int, int], min_dist: float
) -> tuple[int, int] | None:
    """(row, col) of the best score of ``grid`` farther than ``min_dist`` (px) from ``best``.

    Either a second peak (a repeated structure) or a point on a ridge through the best one (all
    edges parallel: the shift along them is unconstrained); both make the best shift ambiguous.
    """
    by, bx = best
    far = np.hypot(xs[None, :] - xs[bx], ys[:, None] - ys[by]) > min_dist
    if not np.any(far & (grid > 0)):
        return None
    i = int(np.argmax(np.where(far, grid, -np.inf)))
    return int(i // grid.shape[1]), int(i % grid.shape[1])


def _fine_search(
    maps: _ScoreMaps,
    pts: np.ndarray,
    bins: np.ndarray,
    centre: np.ndarray,
    radius: int,
    min_inside: float,
    away_from: np.ndarray | None = None,
    min_dist: float = 0.0,
) -> tuple[np.ndarray, float]:
    """Best integer shift within +-radius of ``centre`` (farther than ``min_dist`` from
    ``away_from`` if given) and its score."""
    r = np.arange(-radius, radius + 1, dtype=np.float64)
    gx, gy = np.meshgrid(centre[0] + r, centre[1] + r)
    shifts = np.stack([gx.ravel(), gy.ravel()], axis=1)
    sc = maps.scores(pts, bins, shifts, min_inside)
    if away_from is not None:
        sc = np.where(np.hypot(*(shifts - away_from).T) > min_dist, sc, -1.0)
    i = int(np.argmax(sc))
    return shifts[i], float(sc[i])


def translation_matrix(dx: float, dy: float) -> np.ndarray:
    return np.array([[1.0, 0.0, dx], [0.0, 1.0, dy], [0.0, 0.0, 1.0]])


def rotation_homography(camera_K: np.ndarray, dx: float, dy: float) -> np.ndarray:
    """photo_from_render = K R K^-1 of the camera rotation (no roll) that moves the principal
    point by (dx, dy) px: a shift with the perspective (keystone) of a real rotation."""
    k = np.asarray(camera_K, dtype=np.float64)
    kinv = np.linalg.inv(k)
    a = kinv @ np.array([k[0, 2], k[1, 2], 1.0])
    b = kinv @ np.array([k[0, 2] + dx, k[1, 2] + dy, 1.0])
    a, b = a / np.linalg.norm(a), b / np.linalg.norm(b)
    v, c = np.cross(a, b), float(np.dot(a, b))
    vx = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
    r = np.eye(3) + vx + vx @ vx / (1.0 + c)  # rotation taking a to b (Rodrigues)
    h = k @ r @ kinv
    return h / h[2, 2]


def _polish(
    re: RenderEdges,
    pe: PhotoEdges,
    bins: np.ndarray,
    start: np.ndarray,
    tau: float,
    config: EdgeAlignConfig,
) -> tuple[np.ndarray, float]:
    """``start`` followed by the integer shift within +-``polish_radius_px`` with the best score
    at a narrow truncation (the final Tukey scale), and that score: the wide tau of the search
    favours the middle of a clutter of edges, the narrow one the shift that puts most edges
    exactly on photo edges."""
    r = max(0, int(config.polish_radius_px))
    tau_n = max(config.min_scale_px, config.final_scale * tau)
    sub = _subset(len(re), config.refine_points)
    q0, b = _apply(start, re.points[sub]), bins[sub]
    offs = np.arange(-r, r + 1, dtype=np.float64)
    gx, gy = np.meshgrid(offs, offs)
    shifts = np.stack([gx.ravel(), gy.ravel()], axis=1)
    h, w = pe.height, pe.width
    x = np.floor(q0[None, :, 0] + shifts[:, None, 0] + 0.5).astype(np.int64)
    y = np.floor(q0[None, :, 1] + shifts[:, None, 1] + 0.5).astype(np.int64)
    inside = (x >= 0) & (x < w) & (y >= 0) & (y < h)
    d = pe.oriented_dist[b[None, :], np.clip(y, 0, h - 1), np.clip(x, 0, w - 1)]
    score = np.where(inside, 1.0 - np.minimum(d, tau_n) / tau_n, 0.0).sum(axis=1)
    i = int(np.argmax(score))
    return translation_matrix(*shifts[i]) @ start, float(score[i]) / max(1, len(sub))


def _normaliser(width: int, height: int) -> np.ndarray:
    """T mapping pixels to normalised coordinates (centre 0, half-diagonal 1)."""
    s = 2.0 / math.hypot(width, height)
    return np.array([[s, 0, -s * (width - 1) / 2], [0, s, -s * (height - 1) / 2], [0, 0, 1.0]])


def _apply(h: np.ndarray, pts: np.ndarray) -> np.ndarray:
    ph = pts @ h[:2, :2].T + h[:2, 2]
    wz = pts @ h[2, :2] + h[2, 2]
    return ph / wz[:, None]


def _correspond(
    q: np.ndarray, bins: np.ndarray, pe: PhotoEdges, max_dist: float
) -> tuple[np.ndarray, np.ndarray]:
    """For aligned points q (N, 2): (valid mask, photo edge index) of the nearest compatible edge
    within ``max_dist`` px."""
    h, w = pe.height, pe.width
    x = np.floor(q[:, 0] + 0.5).astype(np.int64)
    y = np.floor(q[:, 1] + 0.5).astype(np.int64)
    inside = (x >= 0) & (x < w) & (y >= 0) & (y < h) & np.all(np.isfinite(q), axis=1)
    d, e = pe.compatible_nearest(bins, np.clip(x, 0, w - 1), np.clip(y, 0, h - 1))
    ok = inside & (d <= max_dist) & (e >= 0)
    return ok, e


def _jacobian(u: np.ndarray, v: np.ndarray, n: np.ndarray, model: str) -> np.ndarray:
    """d(n . q) / d(params) for q = pi((I + A) y), y = (u, v, 1), in normalised coordinates."""
    nx, ny = n[:, 0], n[:, 1]
    if model == "shift":
        return np.stack([nx, ny], axis=1)
    if model == "similarity":  # a1 = a5 = s, a2 = -a4 = -r
        return np.stack([nx * u + ny * v, -nx * v + ny * u, nx, ny], axis=1)
    cols = [nx * u, nx * v, nx, ny * u, ny * v, ny]
    if model == "homography":
        cols += [-(nx * u + ny * v) * u, -(nx * u + ny * v) * v]
    return np.stack(cols, axis=1)


def _update_matrix(delta: np.ndarray, model: str) -> np.ndarray:
    a = np.zeros((3, 3))
    if model == "shift":
        a[0, 2], a[1, 2] = delta
    elif model == "similarity":
        s, r, tx, ty = delta
        a[:2, :] = [[s, -r, tx], [r, s, ty]]
    else:
        a[0, :], a[1, :] = delta[0:3], delta[3:6]
        if model == "homography":
            a[2, :2] = delta[6:8]
    return np.eye(3) + a


def _refine(
    re: RenderEdges,
    pe: PhotoEdges,
    bins: np.ndarray,
    init: np.ndarray,
    tau: float,
    config: EdgeAlignConfig,
) -> np.ndarray:
    """Point-to-line IRLS (Tukey) from ``init`` (3x3 photo_from_render); returns the refined
    photo_from_render (pixels) and its robust cost (lower is better)."""
    t = _normaliser(re.width, re.height)
    t_inv = np.linalg.inv(t)
    hn = t @ init @ t_inv
    sub = _subset(len(re), config.refine_points)
    pn = re.points[sub] @ t[:2, :2].T + t[:2, 2]
    bins = bins[sub]
    scale = t[0, 0]
    corners = image_corners(re.width, re.height) @ t[:2, :2].T + t[:2, 2]
    final = MODELS.index(config.model)
    c_min = min(tau, max(config.min_scale_px, tau * config.final_scale))
    # stages: the models up to the requested one at the Tukey scale tau, then the requested
    # model with the scale annealed to c_min (wide first: large corrections need the far points)
    stages = [(m, tau) for m in MODELS[: final + 1]]
    stages += [(config.model, c) for c in np.geomspace(tau, c_min, 3)[1:]]
    iters = max(1, int(config.iterations))
    per_stage = max(2, iters // len(stages))
    for stage_i, (model, c) in enumerate(stages):
        n_it = per_stage if stage_i < len(stages) - 1 else max(2, iters - per_stage * stage_i)
        for _ in range(n_it):
            qn = _apply(hn, pn)
            q = (qn - t[:2, 2]) / scale
            ok, e = _correspond(q, bins, pe, tau)
            if ok.sum() < _N_PARAMS[model] * 3:
                return t_inv @ hn @ t, math.inf
            nrm = pe.normals[e[ok]]
            r = np.sum(nrm * (q[ok] - pe.points[e[ok]]), axis=1)  # px
            wgt = np.where(np.abs(r) < c, (1 - (r / c) ** 2) ** 2, 0.0)
            jac = _jacobian(qn[ok, 0], qn[ok, 1], nrm, model) / scale  # px per param
            jw = jac * wgt[:, None]
            a = jw.T @ jac
            g = jw.T @ r
            lam = config.damping * float(np.trace(a)) / len(a) + 1e-12
            try:
                delta = -np.linalg.solve(a + lam * np.eye(len(a)), g)
            except np.linalg.LinAlgError:
                return t_inv @ hn @ t, math.inf
            new = _update_matrix(delta, model) @ hn
            new = new / new[2, 2]
            moved = np.abs(_apply(new, corners) - _apply(hn, corners)).max() / scale
            hn = new
            if moved < config.converged_px:
                break
    hmat = t_inv @ hn @ t
    # robust cost at the final scale: Tukey rho (0..1) per point, 1 for unmatched points
    q = _apply(hmat, re.points[sub])
    ok, e = _correspond(q, bins, pe, c_min)
    r = np.sum(pe.normals[e[ok]] * (q[ok] - pe.points[e[ok]]), axis=1)
    rho = 1.0 - (1.0 - np.minimum((r / c_min) ** 2, 1.0)) ** 3
    return hmat, float(rho.sum() + (~ok).sum())


def _support(pts: np.ndarray, bins: np.ndarray, h: np.ndarray, pe: PhotoEdges, tau: float) -> float:
    if len(pts) == 0:
        return 0.0
    ok, _ = _correspond(_apply(h, pts), bins, pe, tau)
    return float(ok.mean())


def auto_tau(width: int, height: int) -> float:
    """Default chamfer truncation (px) for a working image of this size."""
    return max(3.0, 0.0075 * math.hypot(width, height))


def align_edges(
    render_edges: RenderEdges,
    photo_edges: PhotoEdges,
    config: EdgeAlignConfig = EdgeAlignConfig(),
) -> EdgeAlignment:
    """Estimate ``photo_from_render`` aligning the render's geometric edges with the photo's.

    Render and photo must have the same size (the working resolution). Never raises for bad
    data: failures come back with ``success=False`` and an ``EdgeReason``.
    """
    re, pe = render_edges, photo_edges
    if config.model not in MODELS:
        raise ValueError(f"model must be one of {', '.join(MODELS)}, got {config.model!r}")
    if (re.width, re.height) != (pe.width, pe.height):
        raise ValueError(
            f"render edges are {re.width}x{re.height} but photo edges {pe.width}x{pe.height}"
        )
    w, h = re.width, re.height
    diag = math.hypot(w, h)
    tau = float(config.tau_px) if config.tau_px is not None else auto_tau(w, h)
    timings: dict[str, float] = {}
    t0 = time.perf_counter()

    def fail(reason: EdgeReason, **kw) -> EdgeAlignment:
        base = dict(
            success=False,
            reason=reason,
            photo_from_render=None,
            corner_error=float("inf"),
            support=0.0,
            support_identity=0.0,
            residual_px=float("nan"),
            n_edges=len(re),
            n_photo_edges=len(pe),
            score=0.0,
            baseline_score=0.0,
            shift=None,
            second_shift=None,
            second_score=0.0,
            ambiguity=0.0,
            ambiguous=False,
            tau_px=tau,
            model=config.model,
            timings=timings,
        )
        base.update(kw)
        return EdgeAlignment(**base)

    bins = _bins_of(re.normals, pe.n_bins) if len(re) else np.zeros(0, dtype=np.int64)
    support_id = _support(re.points, bins, np.eye(3), pe, tau) if len(pe) else 0.0
    if len(re) < config.min_edges:
        return fail(EdgeReason.TOO_FEW_EDGES, support_identity=support_id)
    if len(pe) < config.min_photo_edges:
        return fail(EdgeReason.TOO_FEW_PHOTO_EDGES)

    # (a) coarse exhaustive shift search
    if config.coarse_step_px is not None:
        step = max(1, int(round(config.coarse_step_px)))
    else:  # ~0.5 % of the diagonal, fine enough for the tau-wide basin of the score
        step = int(max(1, min(max(2, round(0.005 * diag)), math.floor(tau / 1.5))))
    radius = config.search_radius * diag
    n_side = int(math.floor(radius / step))
    offs = np.arange(-n_side, n_side + 1, dtype=np.float64) * step
    maps = _ScoreMaps.build(pe, tau, pad=n_side * step + step + 1)
    gx, gy = np.meshgrid(offs, offs)
    shifts = np.stack([gx.ravel(), gy.ravel()], axis=1)
    sub_c = _subset(len(re), config.coarse_points)
    sc = maps.scores(re.points[sub_c], bins[sub_c], shifts, config.min_inside).reshape(gx.shape)
    timings["coarse"] = time.perf_counter() - t0
    if not np.any(sc > 0):
        return fail(EdgeReason.NO_OVERLAP, support_identity=support_id)
    by, bx = np.unravel_index(int(np.argmax(sc)), sc.shape)
    runner = _separated_runner_up(
        sc, offs, offs, (int(by), int(bx)), config.ambiguity_separation * tau
    )

    # fine 1-px search around the best and the runner-up
    t1 = time.perf_counter()
    sub_f = _subset(len(re), config.fine_points)
    pf, bf = re.points[sub_f], bins[sub_f]
    best_shift, best_score = _fine_search(
        maps, pf, bf, np.array([offs[bx], offs[by]]), step, config.min_inside
    )
    second_shift, second_score = None, 0.0
    if runner is not None:
        sep = config.ambiguity_separation * tau
        s2, sc2 = _fine_search(
            maps,
            pf,
            bf,
            np.array([offs[runner[1]], offs[runner[0]]]),
            step,
            config.min_inside,
            away_from=best_shift,
            min_dist=sep,
        )
        if sc2 > best_score:  # the fine search can swap them
            s2, sc2, best_shift, best_score = best_shift, best_score, s2, sc2
        if sc2 > 0 and np.hypot(*(s2 - best_shift)) > sep:
            second_shift, second_score = s2, sc2
    # ambiguity relative to the typical (median) score of a random shift: dense clutter lifts
    # every score, a true repeat brings the runner-up close to the best
    baseline = float(np.median(sc))
    if second_shift is not None and best_score > baseline:
        ambiguity = max(0.0, (second_score - baseline) / (best_score - baseline))
    else:
        ambiguity = 0.0
    ambiguous = second_shift is not None and ambiguity >= config.ambiguity_ratio
    timings["fine"] = time.perf_counter() - t1

    # (b) refinement
    t2 = time.perf_counter()
    starts = [translation_matrix(*best_shift)]
    if re.camera_K is not None and np.hypot(*best_shift) > 0.5:
        starts.append(rotation_homography(re.camera_K, *best_shift))
    # the start that puts more edges exactly on photo edges (narrow score) is refined
    polished = [_polish(re, pe, bins, h0, tau, config) for h0 in starts]
    start = max(polished, key=lambda hs: hs[1])[0]
    hmat = _refine(re, pe, bins, start, tau, config)[0]
    timings["refine"] = time.perf_counter() - t2

    # evaluation
    q = _apply(hmat, re.points)
    ok, e = _correspond(q, bins, pe, tau)
    support = float(ok.mean())
    nrm = pe.normals[e[ok]]
    res = np.sum(nrm * (q[ok] - pe.points[e[ok]]), axis=1)
    matches = EdgeMatches(
        render_points=re.points[ok].copy(),
        photo_points=q[ok] - res[:, None] * nrm,
        photo_normals=nrm,
        depth=re.depth[ok].copy(),
        residuals=res,
    )
    err = corner_error(hmat, w, h)
    timings["total"] = time.perf_counter() - t0
    out = dict(
        photo_from_render=hmat,
        corner_error=err,
        support=support,
        support_identity=support_id,
        residual_px=float(np.median(np.abs(res))) if len(res) else float("nan"),
        score=best_score,
        baseline_score=baseline,
        shift=(float(best_shift[0]), float(best_shift[1])),
        second_shift=None
        if second_shift is None
        else (float(second_shift[0]), float(second_shift[1])),
        second_score=second_score,
        ambiguity=ambiguity,
        ambiguous=ambiguous,
        matches=matches,
    )
    if check_homography(hmat, w, h) is not None:
        return fail(EdgeReason.ILL_CONDITIONED, **out)
    if ambiguous:
        return fail(EdgeReason.AMBIGUOUS, **out)
    if support < config.min_support:
        return fail(EdgeReason.LOW_SUPPORT, **out)
    logger.debug(
        "edge alignment: corner error %.2f px, support %.2f (identity %.2f), ambiguity %.2f",
        err,
        support,
        support_id,
        ambiguity,
    )
    return EdgeAlignment(
        success=True,
        reason=None,
        model=config.model,
        tau_px=tau,
        n_edges=len(re),
        n_photo_edges=len(pe),
        timings=timings,
        **out,
    )
