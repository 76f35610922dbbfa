"""Exhaustive integer shift search of the truncated oriented chamfer score and the ambiguity of
its best shift (a separated second peak or a ridge)."""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np

from pgt_check.geometry.edges.config import EdgeAlignConfig
from pgt_check.geometry.edges.results import EdgeProblem, PhotoEdges


def bins_of(normals: np.ndarray, n_bins: int) -> np.ndarray:
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


def subset(n: int, k: int) -> np.ndarray:
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


#: Euler-Mascheroni constant (mean of the standard Gumbel distribution)
_EULER_GAMMA = 0.5772156649015329


def null_p_value(
    grid: np.ndarray, xs: np.ndarray, ys: np.ndarray, best: tuple[int, int], min_dist: float,
    min_cells: int = 8,
) -> tuple[float, int]:
    """Significance of the best shift against the null distribution of the same frame.

    The coarse score grid is cut into cells about ``min_dist`` px wide (one peak each); the
    maxima of the cells farther than ``min_dist`` from the best shift are the frame's own
    wrong alignments (the same edges against the same photo, so the clutter, edge density and
    correlation along edges are the frame's own). A Gumbel distribution fitted to them (by
    moments: the maximum of many correlated scores) gives the chance that one cell reaches the
    best score; times the number of cells within ``min_dist`` of the best (the place of the
    alignment, Bonferroni) it is the returned p-value, with the number of null cells.

    What it bounds: on a frame with no true alignment in the search range (a wrong pose whose
    error is not a 2D shift), a chance alignment at a given place (where a PASS must be: near
    the identity) is accepted at level alpha with probability about alpha. A chance
    alignment accepted elsewhere has a large corner error (FAIL, the pose is wrong anyway); the
    test is not corrected for the number of places (it would be for "some alignment exists").
    Too few valid null cells: p = 1 (not testable)."""
    step = float(xs[1] - xs[0]) if len(xs) > 1 else 1.0
    k = max(1, int(math.ceil(min_dist / step)))
    ny, nx = grid.shape
    py, px = (-ny) % k, (-nx) % k
    padded = np.pad(grid, ((0, py), (0, px)), constant_values=-np.inf)
    cells = padded.reshape((ny + py) // k, k, (nx + px) // k, k).max(axis=(1, 3))
    # distance of each cell (its nearest grid point) to the best shift
    cy = np.arange(cells.shape[0]) * k
    cx = np.arange(cells.shape[1]) * k
    by, bx = best
    dy = np.maximum(0, np.maximum(cy - by, by - (cy + k - 1)))
    dx = np.maximum(0, np.maximum(cx - bx, bx - (cx + k - 1)))
    far = np.hypot(dx[None, :] * step, dy[:, None] * step) > min_dist
    null = cells[far & (cells > 0)]
    n_near = max(1, int(np.sum(~far & (cells > 0))))
    if len(null) < min_cells:
        return 1.0, len(null)
    best_score = float(grid[by, bx])
    m, sd = float(np.mean(null)), float(np.std(null, ddof=1))
    if sd <= 0:
        return (0.0 if best_score > m else 1.0), len(null)
    beta = sd * math.sqrt(6.0) / math.pi
    mu = m - _EULER_GAMMA * beta
    z = (best_score - mu) / beta
    p_one = -math.expm1(-math.exp(-z)) if z > -50 else 1.0  # 1 - F(best)
    return float(min(1.0, n_near * p_one)), len(null)


@dataclass(frozen=True)
class ShiftSearch:
    """Outcome of ``search_shifts``: the best integer shift (dx, dy) and its score, the
    separated runner-up (None: none) and its score, the median score of all coarse shifts
    (``baseline``), the ambiguity and whether it makes the best shift ambiguous; ``p_value``
    and ``n_null``: the best shift's significance against the frame's own wrong alignments
    (``null_p_value``)."""

    best_shift: np.ndarray
    best_score: float
    second_shift: np.ndarray | None
    second_score: float
    baseline: float
    ambiguity: float
    ambiguous: bool
    p_value: float = 1.0
    n_null: int = 0


def coarse_step(config: EdgeAlignConfig, diag: float, tau: float) -> int:
    """Step (px) of the coarse shift grid."""
    if config.coarse_step_px is not None:
        return max(1, int(round(config.coarse_step_px)))
    # ~0.5 % of the diagonal, fine enough for the tau-wide basin of the score
    return int(max(1, min(max(2, round(0.005 * diag)), math.floor(tau / 1.5))))


def _fine_peaks(
    maps: _ScoreMaps,
    pf: np.ndarray,
    bf: np.ndarray,
    offs: np.ndarray,
    best: tuple[int, int],
    runner: tuple[int, int] | None,
    step: int,
    sep: float,
    min_inside: float,
) -> tuple[np.ndarray, float, np.ndarray | None, float]:
    """The fine 1-px search around the coarse best (row, col) and the separated runner-up of
    the coarse grid ``offs`` (None: none) on the points ``pf`` (N, 2) with bins ``bf`` (N,):
    (best shift (2,), its score, second shift (2,) or None, its score)."""
    by, bx = best
    best_shift, best_score = _fine_search(
        maps, pf, bf, np.array([offs[bx], offs[by]]), step, min_inside
    )
    second_shift, second_score = None, 0.0
    if runner is not None:
        s2, sc2 = _fine_search(
            maps,
            pf,
            bf,
            np.array([offs[runner[1]], offs[runner[0]]]),
            step,
            min_inside,
            away_from=best_shift,
            min_dist=sep,
        )
        if sc2 > best_score:  # the fine search can swap them
            s2, sc2, best_shift, best_score = best_shift, best_score, s2, sc2
        if sc2 > 0 and np.hypot(*(s2 - best_shift)) > sep:
            second_shift, second_score = s2, sc2
    return best_shift, best_score, second_shift, second_score


def search_shifts(problem: EdgeProblem, timings: dict[str, float]) -> ShiftSearch | None:
    """Coarse exhaustive search of the shift, then 1 px around the best and the separated
    runner-up; None when no shift keeps enough render edges inside the photo. Adds the
    "coarse" and "fine" times (s) to ``timings``."""
    re, pe, bins, tau, config = (problem.render, problem.photo, problem.bins, problem.tau,
                                 problem.config)
    t0 = time.perf_counter()
    diag = math.hypot(re.width, re.height)
    step = coarse_step(config, diag, tau)
    radius = config.search_radius * diag
    n_side = int(math.floor(radius / step))
    offs = np.arange(-n_side, n_side + 1, dtype=np.float64) * step
    maps = _ScoreMaps.build(pe, tau, pad=n_side * step + step + 1)
    gx, gy = np.meshgrid(offs, offs)
    shifts = np.stack([gx.ravel(), gy.ravel()], axis=1)
    sub_c = subset(len(re), config.coarse_points)
    sc = maps.scores(re.points[sub_c], bins[sub_c], shifts, config.min_inside).reshape(gx.shape)
    timings["coarse"] = time.perf_counter() - t0
    if not np.any(sc > 0):
        return None
    by, bx = np.unravel_index(int(np.argmax(sc)), sc.shape)
    sep = config.ambiguity_separation * tau
    runner = _separated_runner_up(sc, offs, offs, (int(by), int(bx)), sep)
    p_value, n_null = null_p_value(sc, offs, offs, (int(by), int(bx)), sep)

    # fine 1-px search around the best and the runner-up
    t1 = time.perf_counter()
    sub_f = subset(len(re), config.fine_points)
    best_shift, best_score, second_shift, second_score = _fine_peaks(
        maps, re.points[sub_f], bins[sub_f], offs, (int(by), int(bx)), runner, step, sep,
        config.min_inside,
    )
    # ambiguity relative to the typical (median) score of a random shift: dense clutter lifts
    # every score, a true repeat brings the runner-up close to the best
    baseline = float(np.median(sc))
    if second_shift is not None and best_score > baseline:
        ambiguity = max(0.0, (second_score - baseline) / (best_score - baseline))
    else:
        ambiguity = 0.0
    ambiguous = second_shift is not None and ambiguity >= config.ambiguity_ratio
    timings["fine"] = time.perf_counter() - t1
    return ShiftSearch(
        best_shift, best_score, second_shift, second_score, baseline, ambiguity, ambiguous,
        p_value, n_null,
    )
