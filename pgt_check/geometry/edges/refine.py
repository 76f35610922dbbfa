"""Robust refinement of ``photo_from_render``: start matrices, narrow-score polish and
point-to-line IRLS (Tukey, Levenberg damping) from shift up to the requested model."""

from __future__ import annotations

import math

import numpy as np

from pgt_check.geometry.edges.config import MODELS, N_PARAMS, EdgeAlignConfig
from pgt_check.geometry.edges.results import EdgeProblem, PhotoEdges
from pgt_check.geometry.edges.search import subset
from pgt_check.geometry.homography import image_corners


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


def polish(problem: EdgeProblem, start: np.ndarray) -> tuple[np.ndarray, float]:
    """``start`` followed by the integer shift within +-``polish_radius_px`` with the best score
    at a narrow truncation (the final Tukey scale), and that score: the wide tau of the search
    favours the middle of a clutter of edges, the narrow one the shift that puts most edges
    exactly on photo edges."""
    re, pe, bins, tau, config = (problem.render, problem.photo, problem.bins, problem.tau,
                                 problem.config)
    r = max(0, int(config.polish_radius_px))
    tau_n = max(config.min_scale_px, config.final_scale * tau)
    sub = subset(len(re), config.refine_points)
    q0, b = warp_points(start, re.points[sub]), bins[sub]
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


def warp_points(h: np.ndarray, pts: np.ndarray) -> np.ndarray:
    ph = pts @ h[:2, :2].T + h[:2, 2]
    wz = pts @ h[2, :2] + h[2, 2]
    return ph / wz[:, None]


def correspond(
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
    return _update_matrices(np.asarray(delta, dtype=np.float64)[None], model)[0]


def _update_matrices(deltas: np.ndarray, model: str) -> np.ndarray:
    """(K, 3, 3) I + A of each parameter step (rows of ``deltas``, (K, P))."""
    a = np.zeros((len(deltas), 3, 3))
    if model == "shift":
        a[:, 0, 2], a[:, 1, 2] = deltas[:, 0], deltas[:, 1]
    elif model == "similarity":
        s, r = deltas[:, 0], deltas[:, 1]
        a[:, 0, 0], a[:, 0, 1], a[:, 0, 2] = s, -r, deltas[:, 2]
        a[:, 1, 0], a[:, 1, 1], a[:, 1, 2] = r, s, deltas[:, 3]
    else:
        a[:, 0, :], a[:, 1, :] = deltas[:, 0:3], deltas[:, 3:6]
        if model == "homography":
            a[:, 2, :2] = deltas[:, 6:8]
    return np.eye(3) + a


def _observable_solve(
    a: np.ndarray,
    g: np.ndarray,
    lam: float,
    hn: np.ndarray,
    corners: np.ndarray,
    scale: float,
    n_weight: float,
    max_gain: float,
    model: str,
) -> np.ndarray:
    """The damped Gauss-Newton step ``(a + lam I)^-1 g`` restricted to the parameter directions
    the edges determine.

    ``a`` = J^T W J over points of total weight ``n_weight`` (residuals in px); along its
    eigen-direction v (eigenvalue e), a coherent misfit of 1 px rms of the edges moves the
    parameters by sqrt(n_weight / e) and the image corners (``corners``, normalised
    coordinates, ``scale`` per px) by that times their motion per unit of v. Directions whose
    corners would move by more than ``max_gain`` px are left where they are: edges constrain a
    motion only across themselves, and lines through one point (a room corner) leave a zoom
    about that point and perspective terms free; the refinement would drift along them with
    the matches' noise and the corner error of a correct pose would not be small (issue #29).
    """
    ev, vecs = np.linalg.eigh(a)
    if not np.all(np.isfinite(ev)):
        raise np.linalg.LinAlgError("non-finite normal equations")
    eps = 1e-6
    base = warp_points(hn, corners)
    keep = np.zeros(len(ev), dtype=bool)
    pos = np.flatnonzero(ev > 0)
    if len(pos):  # all directions at once: this runs at every iteration of every refinement
        mats = _update_matrices(eps * vecs[:, pos].T, model) @ hn
        ph = corners @ mats[:, :2, :2].transpose(0, 2, 1) + mats[:, None, :2, 2]
        moved = ph / (corners @ mats[:, 2, :2, None] + mats[:, None, 2, 2:3])
        per_unit = np.sqrt(np.mean(np.sum((moved - base) ** 2, axis=2), axis=1)) / eps / scale
        keep[pos] = per_unit * np.sqrt(n_weight / ev[pos]) <= max_gain
    proj = vecs[:, keep].T @ g
    return vecs[:, keep] @ (proj / (ev[keep] + lam))


def refine(problem: EdgeProblem, init: np.ndarray) -> tuple[np.ndarray, float]:
    """Point-to-line IRLS (Tukey) from ``init`` (3x3 photo_from_render); returns the refined
    photo_from_render (pixels) and its robust cost (lower is better)."""
    re, pe, bins, tau, config = (problem.render, problem.photo, problem.bins, problem.tau,
                                 problem.config)
    t = _normaliser(re.width, re.height)
    t_inv = np.linalg.inv(t)
    hn = t @ init @ t_inv
    sub = subset(len(re), config.refine_points)
    pn = re.points[sub] @ t[:2, :2].T + t[:2, 2]
    bins = bins[sub]
    scale = t[0, 0]
    corners = image_corners(re.width, re.height) @ t[:2, :2].T + t[:2, 2]
    final = MODELS.index(config.model)
    c_min = final_scale_px(tau, config)
    # stages: the models up to the requested one at the Tukey scale tau, then the requested
    # model with the scale annealed to c_min (wide first: large corrections need the far points)
    stages = [(m, tau) for m in MODELS[: final + 1]]
    stages += [(config.model, c) for c in np.geomspace(tau, c_min, 3)[1:]]
    iters = max(1, int(config.iterations))
    per_stage = max(2, iters // len(stages))
    for stage_i, (model, c) in enumerate(stages):
        n_it = per_stage if stage_i < len(stages) - 1 else max(2, iters - per_stage * stage_i)
        for _ in range(n_it):
            qn = warp_points(hn, pn)
            q = (qn - t[:2, 2]) / scale
            ok, e = correspond(q, bins, pe, tau)
            if ok.sum() < N_PARAMS[model] * 3:
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
                delta = -_observable_solve(
                    a, g, lam, hn, corners, scale, float(wgt.sum()), config.max_corner_gain, model
                )
            except np.linalg.LinAlgError:
                return t_inv @ hn @ t, math.inf
            new = _update_matrix(delta, model) @ hn
            new = new / new[2, 2]
            moved = np.abs(warp_points(new, corners) - warp_points(hn, corners)).max() / scale
            hn = new
            if moved < config.converged_px:
                break
    hmat = t_inv @ hn @ t
    return hmat, robust_cost(hmat, re.points[sub], bins, pe, c_min)


def final_scale_px(tau: float, config: EdgeAlignConfig) -> float:
    """The Tukey scale (px) of the last refinement stage and of ``robust_cost``."""
    return min(tau, max(config.min_scale_px, tau * config.final_scale))


def robust_cost(
    hmat: np.ndarray, pts: np.ndarray, bins: np.ndarray, pe: PhotoEdges, c: float
) -> float:
    """Robust cost of ``hmat`` on render points ``pts`` (N, 2) with orientation ``bins``: the
    Tukey rho (0..1, scale ``c`` px) of each point-to-line residual, 1 for an unmatched point."""
    q = warp_points(hmat, pts)
    ok, e = correspond(q, bins, pe, c)
    r = np.sum(pe.normals[e[ok]] * (q[ok] - pe.points[e[ok]]), axis=1)
    rho = 1.0 - (1.0 - np.minimum((r / c) ** 2, 1.0)) ** 3
    return float(rho.sum() + (~ok).sum())


def support_at(
    pts: np.ndarray, bins: np.ndarray, h: np.ndarray, pe: PhotoEdges, tau: float
) -> float:
    if len(pts) == 0:
        return 0.0
    ok, _ = correspond(warp_points(h, pts), bins, pe, tau)
    return float(ok.mean())
