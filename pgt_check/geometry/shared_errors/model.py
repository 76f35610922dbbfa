"""The fitting problem: all frames' points about the camera centroid, the model state, and the
residuals / Jacobians of the observation model (see the package docstring)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from pgt_check.geometry.shared_errors.evidence import FrameEvidence


@dataclass(frozen=True, eq=False)
class _Problem:
    origin: np.ndarray  # (3,) camera centroid (world)
    frame_ids: tuple[str, ...]  # (F,) sorted by index
    index: np.ndarray  # (F,) int
    cam: np.ndarray  # (F,) int camera-group of each frame
    camera_ids: tuple[str, ...]  # (G,)
    rt: np.ndarray  # (F, 3, 3) cam_from_world rotation
    centre: np.ndarray  # (F, 3) camera centre relative to origin
    K: np.ndarray  # (F, 3, 3)
    y: np.ndarray  # (N, 3) world points relative to origin
    obs: np.ndarray  # (N, 2) photo pixels
    fidx: np.ndarray  # (N,) frame of each point (contiguous, non-decreasing)
    starts: np.ndarray  # (F,) first point of each frame
    #: calibration parameters per camera group: 4 (rotation, log zoom) or 7 (+ camera-frame
    #: translation, fitted where the points' depths differ enough to tell it from a rotation)
    n_cal: int = 4

    @property
    def n_frames(self) -> int:
        return len(self.frame_ids)

    @property
    def n_cams(self) -> int:
        return len(self.camera_ids)


@dataclass(frozen=True, eq=False)
class _State:
    q: np.ndarray  # (3, 3) rotation of D
    tau: np.ndarray  # (3,)
    log_sigma: float
    rcal: np.ndarray  # (G, 3, 3) true_cam_from_checked_cam rotation
    log_zoom: np.ndarray  # (G,)
    tcal: np.ndarray  # (G, 3) true_cam_from_checked_cam translation (checked-camera units)

    @staticmethod
    def identity(n_cams: int) -> _State:
        return _State(
            np.eye(3),
            np.zeros(3),
            0.0,
            np.tile(np.eye(3), (n_cams, 1, 1)),
            np.zeros(n_cams),
            np.zeros((n_cams, 3)),
        )

    def with_world(self, other: _State) -> _State:
        """This state's calibration with ``other``'s world map."""
        return _State(other.q, other.tau, other.log_sigma, self.rcal, self.log_zoom, self.tcal)


def _rodrigues(v: np.ndarray) -> np.ndarray:
    """(..., 3) rotation vectors -> (..., 3, 3) rotations."""
    v = np.asarray(v, np.float64)
    th = np.linalg.norm(v, axis=-1)[..., None, None]
    k = np.zeros(v.shape[:-1] + (3, 3))
    k[..., 0, 1], k[..., 0, 2], k[..., 1, 2] = -v[..., 2], v[..., 1], -v[..., 0]
    k[..., 1, 0], k[..., 2, 0], k[..., 2, 1] = v[..., 2], -v[..., 1], v[..., 0]
    small = th < 1e-8
    ths = np.where(small, 1.0, th)
    a = np.where(small, 1.0 - th**2 / 6, np.sin(ths) / ths)
    b = np.where(small, 0.5 - th**2 / 24, (1 - np.cos(ths)) / ths**2)
    return np.eye(3) + a * k + b * (k @ k)


def _rotvec(r: np.ndarray) -> np.ndarray:
    """(..., 3, 3) rotations -> (..., 3) rotation vectors (angles < 180 deg)."""
    c = np.clip((np.trace(r, axis1=-2, axis2=-1) - 1) / 2, -1, 1)
    th = np.arccos(c)
    w = np.stack(
        [r[..., 2, 1] - r[..., 1, 2], r[..., 0, 2] - r[..., 2, 0], r[..., 1, 0] - r[..., 0, 1]],
        axis=-1,
    )
    s = np.sin(th)
    f = np.where(th < 1e-8, 0.5, th / (2 * np.where(th < 1e-8, 1.0, s)))
    return w * f[..., None]


def _bmv(m: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Per-point matrix-vector product: m (N, R, 3), x (..., N, 3) -> (..., N, R)."""
    return m[..., 0] * x[..., 0:1] + m[..., 1] * x[..., 1:2] + m[..., 2] * x[..., 2:3]


def _angle_deg(r: np.ndarray) -> np.ndarray:
    c = np.clip((np.trace(r, axis1=-2, axis2=-1) - 1) / 2, -1, 1)
    return np.degrees(np.arccos(c))


def _prepare(
    evidence: Sequence[FrameEvidence],
    min_points_per_frame: int,
    min_frames: int,
    translation: bool = False,
) -> _Problem | str:
    """Concatenate usable points; a reason string when there is too little to fit.
    ``translation``: the calibration block gets a camera-frame translation where the points'
    inverse depths spread enough (``RIG_TRANSLATION_MIN_SPREAD``) to tell it from a rotation."""
    usable = []
    for ev in evidence:
        if not (np.all(np.isfinite(ev.world_from_cam)) and np.all(np.isfinite(ev.K))):
            continue
        ok = np.all(np.isfinite(ev.pts2d), axis=1) & np.all(np.isfinite(ev.pts3d), axis=1)
        r = ev.world_from_cam[:3, :3]
        t = ev.world_from_cam[:3, 3]
        z = (ev.pts3d[ok] - t) @ r[:, 2]
        keep = np.flatnonzero(ok)[z > 1e-9 * max(1.0, float(np.abs(t).max()))]
        if len(keep) >= min_points_per_frame:
            usable.append((ev, keep))
    if len(usable) < min_frames:
        return "too_few_frames" if len(evidence) < min_frames else "too_few_points"
    usable.sort(key=lambda e: e[0].index)
    origin = np.mean([ev.world_from_cam[:3, 3] for ev, _ in usable], axis=0)
    inv_depth = np.concatenate(
        [1.0 / ((ev.pts3d[k] - ev.world_from_cam[:3, 3]) @ ev.world_from_cam[:3, 2])
         for ev, k in usable]
    )  # fmt: skip
    camera_ids = tuple(sorted({ev.camera_id for ev, _ in usable}))
    counts = np.array([len(k) for _, k in usable])
    return _Problem(
        origin=origin,
        frame_ids=tuple(ev.frame_id for ev, _ in usable),
        index=np.array([ev.index for ev, _ in usable], int),
        cam=np.array([camera_ids.index(ev.camera_id) for ev, _ in usable], int),
        camera_ids=camera_ids,
        rt=np.stack([ev.world_from_cam[:3, :3].T for ev, _ in usable]),
        centre=np.stack([ev.world_from_cam[:3, 3] - origin for ev, _ in usable]),
        K=np.stack([ev.K for ev, _ in usable]),
        y=np.concatenate([ev.pts3d[k] - origin for ev, k in usable]),
        obs=np.concatenate([ev.pts2d[k] for ev, k in usable]),
        fidx=np.repeat(np.arange(len(usable)), counts),
        starts=np.concatenate([[0], np.cumsum(counts)[:-1]]),
        n_cal=7 if translation and depth_spread(inv_depth) >= RIG_TRANSLATION_MIN_SPREAD else 4,
    )


#: a camera-frame translation is fitted when the inverse depths of the points spread by this
#: much (``depth_spread``): its image effect (f t / z) is then told from a rotation's (f theta)
RIG_TRANSLATION_MIN_SPREAD = 0.5


def depth_spread(inv_depth: np.ndarray) -> float:
    """(p90 - p10) / median of the points' inverse depths (0 for a fronto-parallel scene)."""
    v = np.asarray(inv_depth, np.float64)
    v = v[np.isfinite(v) & (v > 0)]
    if len(v) < 10:
        return 0.0
    lo, med, hi = np.percentile(v, [10, 50, 90])
    return float((hi - lo) / med)


def _subset(p: _Problem, frames: np.ndarray) -> _Problem:
    """The sub-problem of the given frame positions (sorted), same origin and camera groups."""
    frames = np.asarray(frames, int)
    pts = np.isin(p.fidx, frames)
    remap = np.full(p.n_frames, -1)
    remap[frames] = np.arange(len(frames))
    counts = np.bincount(p.fidx[pts], minlength=p.n_frames)[frames]
    return _Problem(
        origin=p.origin,
        frame_ids=tuple(p.frame_ids[i] for i in frames),
        index=p.index[frames],
        cam=p.cam[frames],
        camera_ids=p.camera_ids,
        rt=p.rt[frames],
        centre=p.centre[frames],
        K=p.K[frames],
        y=p.y[pts],
        obs=p.obs[pts],
        fidx=remap[p.fidx[pts]],
        starts=np.concatenate([[0], np.cumsum(counts)[:-1]]),
        n_cal=p.n_cal,
    )


def _layout(p: _Problem, world: bool, similarity: bool, calib: bool) -> tuple[int, int, int]:
    """(number of world columns, offset of the calibration columns, total columns)."""
    nw = (7 if similarity else 6) if world else 0
    return nw, nw, nw + (p.n_cal * p.n_cams if calib else 0)


def _residuals(
    p: _Problem,
    st: _State,
    *,
    jac: bool = False,
    world: bool = True,
    similarity: bool = False,
    calib: bool = False,
) -> tuple[np.ndarray, np.ndarray | None]:
    """Residuals (N, 2) = predicted - observed, and the Jacobian (N, 2, P) of the active blocks.

    Column order: world [rotation (3), translation (3), log scale (1, similarity)], then per
    camera [rotation (3), log zoom (1), translation (3) when ``p.n_cal`` is 7].
    Written row by row with explicit cross products: the run-level checks call it some hundred
    times per run, and numpy's batched (N, 2, 3) @ (N, 3, 3) products and ``np.cross`` were most
    of their time (reports/pipeline_timing.md).
    """
    sig = np.exp(st.log_sigma)
    w = sig * (p.y @ st.q.T)  # (N, 3): sigma Q Y
    f = p.fidx
    g = p.cam[f]
    xw = w + st.tau - p.centre[f]
    mf = (st.rcal[p.cam] @ p.rt)[f]  # (N, 3, 3) true_cam_from_world rotation of each point
    xr = _bmv(mf, xw)  # rotated into the true camera, before the calibration translation
    xp = xr + st.tcal[g]
    fx, sk, fy, cx, cy = p.K[:, (0, 0, 1, 0, 1), (0, 1, 1, 2, 2)][f].T
    z = xp[:, 2]
    m0 = (fx * xp[:, 0] + sk * xp[:, 1]) / z
    m1 = fy * xp[:, 1] / z
    e = np.exp(st.log_zoom[g])
    pred = np.stack([cx + e * m0, cy + e * m1], axis=1)
    r = pred - p.obs
    if not jac:
        return r, None
    nw, off, ncol = _layout(p, world, similarity, calib)
    n = len(r)
    ez = e / z
    # the two rows of d pred / d xp, (N, 3) each
    d = (np.stack([ez * fx, ez * sk, -ez * m0], axis=1),
         np.stack([np.zeros(n), ez * fy, -ez * m1], axis=1))
    jm = np.zeros((n, 2, ncol))
    if world:
        for row, dr in enumerate(d):
            a = dr[:, 0:1] * mf[:, 0] + dr[:, 1:2] * mf[:, 1] + dr[:, 2:3] * mf[:, 2]
            jm[:, row, 0:3] = _cross(w, a)  # d pred / d (rotation of D(Y))
            jm[:, row, 3:6] = a
            if similarity:
                jm[:, row, 6] = np.sum(a * w, axis=1)
    if calib:
        jz = (e * m0, e * m1)
        blocks = [slice(None)] if p.n_cams == 1 else [g == gi for gi in range(p.n_cams)]
        for gi, sel in enumerate(blocks):
            c0 = off + p.n_cal * gi
            for row, dr in enumerate(d):
                # the rotation update turns xr, not the translation added after it
                jm[sel, row, c0 : c0 + 3] = _cross(xr[sel], dr[sel])
                jm[sel, row, c0 + 3] = jz[row][sel]
                if p.n_cal == 7:
                    jm[sel, row, c0 + 4 : c0 + 7] = dr[sel]
    return r, jm


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise cross product of (N, 3) arrays (``np.cross`` without its broadcasting set-up)."""
    a0, a1, a2 = a[:, 0], a[:, 1], a[:, 2]
    b0, b1, b2 = b[:, 0], b[:, 1], b[:, 2]
    return np.stack([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0], axis=1)


def _update(
    p: _Problem, st: _State, delta: np.ndarray, world: bool, similarity: bool, calib: bool
) -> _State:
    nw, off, _ = _layout(p, world, similarity, calib)
    q, tau, ls, rcal, lz, tc = st.q, st.tau, st.log_sigma, st.rcal, st.log_zoom, st.tcal
    if world:
        q = _rodrigues(delta[0:3]) @ q
        tau = tau + delta[3:6]
        if similarity:
            ls = ls + float(delta[6])
    if calib:
        dc = delta[off:].reshape(-1, p.n_cal)
        rcal = _rodrigues(dc[:, :3]) @ rcal
        lz = lz + dc[:, 3]
        if p.n_cal == 7:
            tc = tc + dc[:, 4:7]
    return _State(q, tau, ls, rcal, lz, tc)
