"""A start for the refinement from local shifts: the best shift of the render edges of each
image tile, near the global best shift, and the affine map that fits those tile shifts.

A single shift cannot start a motion that varies across the image by more than the Tukey
scale (a camera moved towards the scene by a few % zooms the image; a translation moves near
parts more than far ones): the refinement then ignores the far-off edges as outliers and stops
short of the zoom (a moved castle trajectory: reports/shared_errors_tiles.md). The tile shifts
see the variation directly."""

from __future__ import annotations

import math

import numpy as np

from pgt_check.geometry.edges.results import EdgeProblem
from pgt_check.geometry.edges.search import _ScoreMaps, subset

#: tiles with fewer render edge points are left out
TILE_MIN_POINTS = 40
#: render edge points over all tiles (evenly spread subset)
TILE_POINTS = 3000


def _tile_shift(
    maps: _ScoreMaps, pts: np.ndarray, bins: np.ndarray, centre: np.ndarray, radius: int,
    step: int, min_inside: float,
) -> np.ndarray:
    """Best integer shift of ``pts`` within +-``radius`` of ``centre``: a ``step`` px grid (the
    score's basin is tau wide), then 1 px around its best."""
    best = centre
    for grid_step, r in ((step, radius), (1, step)):
        offs = np.arange(-r, r + 1, grid_step, dtype=np.float64)
        gx, gy = np.meshgrid(best[0] + offs, best[1] + offs)
        shifts = np.stack([gx.ravel(), gy.ravel()], axis=1)
        best = shifts[int(np.argmax(maps.scores(pts, bins, shifts, min_inside)))]
    return best


def tile_start(problem: EdgeProblem, shift: np.ndarray) -> np.ndarray | None:
    """photo_from_render (3x3 affine) fitting the best shifts of ``config.tile_grid`` x
    ``config.tile_grid`` tiles (each searched within +-``config.tile_radius`` x diagonal of
    ``shift``; RANSAC over the tile centres, inlier distance tau / 2, at least 3 px); None
    with the tiles off, fewer than 4 tiles with enough edges or no consistent affine map.

    Not limited to large shifts: frames whose motion partly cancels in the mean shift (a
    rotation against a translation) still vary across the image; trying the tiles only from a
    best shift of tau on made the pooled estimate worse (7-Scenes calibrated on a trusted run,
    2 deg + 4 %: angle off by 60 % instead of 6 %)."""
    import cv2

    re, pe, bins, tau, config = (problem.render, problem.photo, problem.bins, problem.tau,
                                 problem.config)
    grid = int(config.tile_grid)
    shift = np.asarray(shift, dtype=np.float64)
    if grid < 2 or len(re) == 0:
        return None
    radius = max(2, int(round(config.tile_radius * math.hypot(re.width, re.height))))
    step = max(1, int(tau // 3))
    maps = _ScoreMaps.build(pe, tau, pad=int(np.abs(shift).max()) + radius + 4)
    sub = subset(len(re), TILE_POINTS)
    pts, b = re.points[sub], bins[sub]
    tx = np.clip((pts[:, 0] / re.width * grid).astype(np.int64), 0, grid - 1)
    ty = np.clip((pts[:, 1] / re.height * grid).astype(np.int64), 0, grid - 1)
    src, dst = [], []
    for tile in range(grid * grid):
        m = tx + grid * ty == tile
        if m.sum() < TILE_MIN_POINTS:
            continue
        s = _tile_shift(maps, pts[m], b[m], shift, radius, step, config.min_inside)
        c = pts[m].mean(axis=0)
        src.append(c)
        dst.append(c + s)
    if len(src) < 4:
        return None
    a, _ = cv2.estimateAffine2D(
        np.asarray(src), np.asarray(dst), ransacReprojThreshold=max(3.0, 0.5 * tau)
    )
    if a is None or not np.all(np.isfinite(a)):
        return None
    return np.vstack([a, [0.0, 0.0, 1.0]])
