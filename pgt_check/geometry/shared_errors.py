"""Run-level shared-error estimators: registration, drift and calibration from pooled evidence.

Per-frame checks cannot see an error that all frames share (see ``docs/evidence.md``). Here the
absolute evidence of many frames is pooled: each frame contributes 2D-3D correspondences (photo
keypoint in photo pixels <-> world point from the render depth, ``pnp.lift_keypoints``), and one
small model of the shared error is fitted to all of them at once.

Observation model for point ``X`` seen in frame ``i`` of camera ``g``::

    u = pi(K_i * zoom_g, R_g @ cam_from_world_i @ D(X)),   D = corrected_world_from_world^-1

* ``D`` (world, about the camera centroid ``c``): ``D(X) = sigma Q (X - c) + c + tau``; rigid
  (``sigma = 1``) or similarity. The reported correction is its inverse ``C``: the corrected pose
  of frame ``i`` is ``C @ world_from_cam_i`` (centre mapped by ``C``, rotation ``R_C R_i``).
* ``R_g, zoom_g`` (camera frame, per ``camera_id``): a camera-to-rig rotation and a focal scale.
  A rotation about the camera x/y axes is the physical form of a principal-point shift
  (``dx ~ fx * ry``, ``dy ~ -fy * rx``, exact at the image centre, keystone at the edges) and
  the rotation about z is the roll. The rotation form is used because the real case (the RGB
  camera of 7-Scenes sits rotated against the depth camera whose poses are given) is a rotation.

Fitting: Gauss-Newton / IRLS with analytic Jacobians and a Cauchy loss, graduated from a wide
scale to ``loss_scale_px`` (robust to 30-80 % outliers without a RANSAC stage: the shared error
is small, so identity is a good start). Own solver instead of ``scipy.optimize.least_squares``
or pycolmap's generalized absolute pose: the model has 6-7 + 4 per camera parameters, the
residuals are vectorised over all points, and the bootstrap reuses per-frame normal-equation
blocks (one-step bootstrap: resampling frames with replacement = integer frame weights, one
Gauss-Newton step from the point estimate), so 100 rounds cost a few small solves.
Everything is float64 relative to the camera centroid, so georeferenced coordinates work.

Registration and calibration are fitted jointly when the parameter blocks are separable (largest
canonical correlation between the world block and a camera's block below ``max_correlation``);
otherwise each is fitted alone and marked ambiguous.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from pgt_check.types import check_shape

logger = logging.getLogger(__name__)

#: closed set of failure reasons
REASONS = (
    "too_few_frames",
    "too_few_points",
    "too_few_inliers",
    "ill_conditioned",
)

_CI = tuple[float, float]
_NAN_CI: _CI = (float("nan"), float("nan"))


# --------------------------------------------------------------------------------------------
# Evidence
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class FrameEvidence:
    """Absolute evidence of one frame.

    world_from_cam: (4, 4) float64, the checked pose; K: (3, 3) photo intrinsics (OpenCV pixel
    centres); pts2d: (N, 2) photo pixels; pts3d: (N, 3) world points (lifted render keypoints).
    ``index`` is the position along the trajectory (for drift windows).
    """

    frame_id: str
    index: int
    camera_id: str
    world_from_cam: np.ndarray
    K: np.ndarray
    width: int
    height: int
    pts2d: np.ndarray
    pts3d: np.ndarray

    def __post_init__(self) -> None:
        for name, shape in (("world_from_cam", (4, 4)), ("K", (3, 3))):
            arr = np.asarray(getattr(self, name), dtype=np.float64)
            check_shape(name, arr, shape)
            object.__setattr__(self, name, arr)
        p2 = np.asarray(self.pts2d, dtype=np.float64).reshape(-1, 2)
        p3 = np.asarray(self.pts3d, dtype=np.float64).reshape(-1, 3)
        if len(p2) != len(p3):
            raise ValueError(f"pts2d has {len(p2)} rows, pts3d {len(p3)}")
        object.__setattr__(self, "pts2d", p2)
        object.__setattr__(self, "pts3d", p3)

    def to_json(self) -> dict:
        """Plain dict (pixels to 1e-3, world points to 1e-5 scene units, pose in full)."""
        return {
            "frame_id": self.frame_id,
            "index": int(self.index),
            "camera_id": self.camera_id,
            "world_from_cam": self.world_from_cam.tolist(),
            "K": np.round(self.K, 6).tolist(),
            "width": int(self.width),
            "height": int(self.height),
            "pts2d": np.round(self.pts2d, 3).tolist(),
            "pts3d": np.round(self.pts3d, 5).tolist(),
        }

    @classmethod
    def from_json(cls, d: dict) -> FrameEvidence:
        return cls(
            frame_id=str(d["frame_id"]),
            index=int(d["index"]),
            camera_id=str(d["camera_id"]),
            world_from_cam=np.asarray(d["world_from_cam"], np.float64),
            K=np.asarray(d["K"], np.float64),
            width=int(d["width"]),
            height=int(d["height"]),
            pts2d=np.asarray(d["pts2d"], np.float64).reshape(-1, 2),
            pts3d=np.asarray(d["pts3d"], np.float64).reshape(-1, 3),
        )


# --------------------------------------------------------------------------------------------
# Results
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class RegistrationEstimate:
    """One world correction for the whole trajectory (or one drift window).

    corrected_world_from_world: (4, 4) rigid or similarity; corrected pose = it @ world_from_cam
    (use ``correct`` to get a rigid pose back for a similarity). Angles in degrees, translation
    in scene units (displacement of the camera centroid), ``effect_px`` the median over frames of
    the mean image displacement of the frame's inlier points when the correction is applied.
    ``*_ci``: 95 % bootstrap intervals over frames.
    """

    success: bool
    reason: str  # "" on success
    corrected_world_from_world: np.ndarray | None = None
    angle_deg: float = float("nan")
    angle_deg_ci: _CI = _NAN_CI
    translation: float = float("nan")
    translation_ci: _CI = _NAN_CI
    translation_frac: float = float("nan")  # translation / median scene depth
    translation_frac_ci: _CI = _NAN_CI
    scale: float = 1.0
    scale_ci: _CI = (1.0, 1.0)
    effect_px: float = float("nan")
    effect_px_ci: _CI = _NAN_CI
    effect_px_per_frame: np.ndarray = field(default_factory=lambda: np.zeros(0))
    frame_ids: tuple[str, ...] = ()
    median_scene_depth: float = float("nan")
    n_frames: int = 0
    n_points: int = 0
    n_inliers: int = 0
    residual_median_before: float = float("nan")  # px, over the final inliers
    residual_median_after: float = float("nan")
    similarity: bool = False
    calibration_fitted: bool = False  # per-camera calibration fitted jointly as nuisance
    ambiguous_with_calibration: bool = False  # not separable: may be a calibration error
    max_correlation: float = float("nan")  # largest canonical corr. world vs calibration

    def exceeds(self, threshold_px: float) -> bool:
        """True when the lower 95 % bound of the pixel effect exceeds ``threshold_px``."""
        if not self.success:
            return False
        low = self.effect_px_ci[0]
        return bool((low if np.isfinite(low) else self.effect_px) > threshold_px)

    def correct(self, world_from_cam: np.ndarray) -> np.ndarray:
        """Apply the correction to one (4, 4) pose; returns a rigid (4, 4) pose."""
        if self.corrected_world_from_world is None:
            raise ValueError(f"no correction ({self.reason})")
        m = self.corrected_world_from_world
        s = float(np.cbrt(np.linalg.det(m[:3, :3])))
        out = np.eye(4)
        out[:3, :3] = (m[:3, :3] / s) @ world_from_cam[:3, :3]
        out[:3, 3] = m[:3, :3] @ world_from_cam[:3, 3] + m[:3, 3]
        return out

    def to_json(self) -> dict:
        return _to_json(self)


@dataclass(frozen=True, eq=False)
class CalibrationEstimate:
    """Shared camera-frame error of one camera (all its frames).

    rotation: (3, 3) ``true_cam_from_checked_cam`` (x_true = rotation @ x_checked): the
    camera-to-rig rotation error; ``rotvec_deg`` its rotation vector (x, y, z = roll) in degrees.
    ``principal_point_shift_px``: the equivalent principal-point shift at the image centre.
    ``focal_scale``: observed focal / given focal. ``effect_px``: median over frames of the mean
    image displacement of the frame's points. ``separable``: False when the error cannot be told
    apart from a world registration error (then this is a calibration-only fit).
    """

    success: bool
    reason: str
    camera_id: str
    rotation: np.ndarray | None = None
    rotvec_deg: np.ndarray = field(default_factory=lambda: np.full(3, np.nan))
    rotvec_deg_ci: np.ndarray = field(default_factory=lambda: np.full((3, 2), np.nan))
    equivalent_rotation_deg: float = float("nan")
    equivalent_rotation_deg_ci: _CI = _NAN_CI
    principal_point_shift_px: np.ndarray = field(default_factory=lambda: np.full(2, np.nan))
    principal_point_shift_px_ci: np.ndarray = field(default_factory=lambda: np.full((2, 2), np.nan))
    roll_deg: float = float("nan")
    roll_deg_ci: _CI = _NAN_CI
    focal_scale: float = float("nan")
    focal_scale_ci: _CI = _NAN_CI
    effect_px: float = float("nan")
    effect_px_ci: _CI = _NAN_CI
    n_frames: int = 0
    n_points: int = 0
    n_inliers: int = 0
    separable: bool = True
    max_correlation: float = float("nan")
    registration_fitted: bool = False  # world correction fitted jointly

    def exceeds(self, threshold_px: float) -> bool:
        """True when the lower 95 % bound of the pixel effect exceeds ``threshold_px``."""
        if not self.success:
            return False
        low = self.effect_px_ci[0]
        return bool((low if np.isfinite(low) else self.effect_px) > threshold_px)

    def to_json(self) -> dict:
        return _to_json(self)


@dataclass(frozen=True, eq=False)
class DriftWindow:
    """A window ``[start, stop)`` of trajectory indices and its correction relative to the
    reference registration (angle, translation, pixel effect with 95 % CIs)."""

    start: int
    stop: int
    estimate: RegistrationEstimate
    flagged: bool


@dataclass(frozen=True, eq=False)
class DriftEstimate:
    """Windowed corrections along the trajectory relative to the reference registration.

    frame_score_px / frame_score_low_px: (F,) per-frame drift score (pixel effect of the local
    correction, and its lower 95 % bound, interpolated between window centres) in the order of
    ``frame_ids`` (sorted by index). ``segments``: flagged runs as (first index, last index).
    """

    success: bool
    reason: str
    reference: RegistrationEstimate | None = None
    windows: tuple[DriftWindow, ...] = ()
    frame_ids: tuple[str, ...] = ()
    frame_index: np.ndarray = field(default_factory=lambda: np.zeros(0, int))
    frame_score_px: np.ndarray = field(default_factory=lambda: np.zeros(0))
    frame_score_low_px: np.ndarray = field(default_factory=lambda: np.zeros(0))
    frame_flagged: np.ndarray = field(default_factory=lambda: np.zeros(0, bool))
    segments: tuple[tuple[int, int], ...] = ()
    threshold_px: float = float("nan")

    def to_json(self) -> dict:
        return _to_json(self)


def _to_json(obj) -> dict:
    out = {}
    for k, v in obj.__dict__.items():
        if isinstance(v, np.ndarray):
            out[k] = np.round(v.astype(np.float64), 6).tolist() if v.dtype != bool else v.tolist()
        elif isinstance(v, RegistrationEstimate | DriftWindow):
            out[k] = _to_json(v)
        elif isinstance(v, tuple) and v and isinstance(v[0], DriftWindow):
            out[k] = [_to_json(w) for w in v]
        elif isinstance(v, float | np.floating):
            out[k] = None if not np.isfinite(v) else round(float(v), 6)
        elif isinstance(v, tuple):
            out[k] = [(None if isinstance(x, float) and not np.isfinite(x) else x) for x in v]
        else:
            out[k] = v
    return out


# --------------------------------------------------------------------------------------------
# The problem: all frames' points, concatenated and expressed about the camera centroid
# --------------------------------------------------------------------------------------------


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
    rcal: np.ndarray  # (G, 3, 3) true_cam_from_checked_cam
    log_zoom: np.ndarray  # (G,)

    @staticmethod
    def identity(n_cams: int) -> _State:
        return _State(
            np.eye(3), np.zeros(3), 0.0, np.tile(np.eye(3), (n_cams, 1, 1)), np.zeros(n_cams)
        )


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


def _normal_equations(jm: np.ndarray, wgt: np.ndarray, r: np.ndarray):
    """H = J^T W J (P, P) and g = J^T W r (P,) for J (N, 2, P), weights (N,), r (N, 2)."""
    sw = np.sqrt(wgt)[:, None, None]
    jw = (jm * sw).reshape(-1, jm.shape[2])
    return jw.T @ jw, jw.T @ (r[:, :, None] * sw).reshape(-1)


def _angle_deg(r: np.ndarray) -> np.ndarray:
    c = np.clip((np.trace(r, axis1=-2, axis2=-1) - 1) / 2, -1, 1)
    return np.degrees(np.arccos(c))


def _prepare(
    evidence: Sequence[FrameEvidence], min_points_per_frame: int, min_frames: int
) -> _Problem | str:
    """Concatenate usable points; a reason string when there is too little to fit."""
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
    )


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
    )


# --------------------------------------------------------------------------------------------
# Residuals and Jacobians
# --------------------------------------------------------------------------------------------


def _layout(p: _Problem, world: bool, similarity: bool, calib: bool) -> tuple[int, int, int]:
    """(number of world columns, offset of the calibration columns, total columns)."""
    nw = (7 if similarity else 6) if world else 0
    return nw, nw, nw + (4 * p.n_cams if calib else 0)


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
    camera [rotation (3), log zoom (1)].
    """
    sig = np.exp(st.log_sigma)
    w = sig * (p.y @ st.q.T)  # (N, 3): sigma Q Y
    f = p.fidx
    g = p.cam[f]
    xw = w + st.tau - p.centre[f]
    m_f = st.rcal[p.cam] @ p.rt  # (F, 3, 3) true_cam_from_world rotation
    xp = _bmv(m_f[f], xw)
    k = p.K[f]
    fx, sk, fy = k[:, 0, 0], k[:, 0, 1], k[:, 1, 1]
    z = xp[:, 2]
    m0 = (fx * xp[:, 0] + sk * xp[:, 1]) / z
    m1 = fy * xp[:, 1] / z
    e = np.exp(st.log_zoom[g])
    pred = np.stack([k[:, 0, 2] + e * m0, k[:, 1, 2] + e * m1], axis=1)
    r = pred - p.obs
    if not jac:
        return r, None
    nw, off, ncol = _layout(p, world, similarity, calib)
    n = len(r)
    d = np.zeros((n, 2, 3))  # d pred / d xp
    d[:, 0, 0] = e * fx / z
    d[:, 0, 1] = e * sk / z
    d[:, 0, 2] = -e * m0 / z
    d[:, 1, 1] = e * fy / z
    d[:, 1, 2] = -e * m1 / z
    jm = np.zeros((n, 2, ncol))
    if world:
        a = d @ m_f[f]  # d pred / d (D(Y))
        jm[:, :, 0:3] = np.cross(w[:, None, :], a)
        jm[:, :, 3:6] = a
        if similarity:
            jm[:, :, 6] = np.sum(a * w[:, None, :], axis=2)
    if calib:
        jr = np.cross(xp[:, None, :], d)
        jz = np.stack([e * m0, e * m1], axis=1)
        for gi in range(p.n_cams):
            sel = g == gi
            c0 = off + 4 * gi
            jm[sel, :, c0 : c0 + 3] = jr[sel]
            jm[sel, :, c0 + 3] = jz[sel]
    return r, jm


def _update(
    p: _Problem, st: _State, delta: np.ndarray, world: bool, similarity: bool, calib: bool
) -> _State:
    nw, off, _ = _layout(p, world, similarity, calib)
    q, tau, ls, rcal, lz = st.q, st.tau, st.log_sigma, st.rcal, st.log_zoom
    if world:
        q = _rodrigues(delta[0:3]) @ q
        tau = tau + delta[3:6]
        if similarity:
            ls = ls + float(delta[6])
    if calib:
        dc = delta[off:].reshape(-1, 4)
        rcal = _rodrigues(dc[:, :3]) @ rcal
        lz = lz + dc[:, 3]
    return _State(q, tau, ls, rcal, lz)


def _cauchy_weights(r: np.ndarray, scale: float) -> np.ndarray:
    rn2 = np.sum(r * r, axis=1)
    return 1.0 / (1.0 + rn2 / scale**2)


@dataclass(frozen=True, eq=False)
class _Fit:
    state: _State
    weights: np.ndarray  # (N,) robust weights at the solution
    residuals: np.ndarray  # (N, 2)
    jac: np.ndarray  # (N, 2, P)
    hessian: np.ndarray  # (P, P)
    ok: bool


def _solve(
    p: _Problem,
    st: _State,
    *,
    world: bool,
    similarity: bool,
    calib: bool,
    loss_scale_px: float,
    frame_w: np.ndarray | None = None,
    anneal: bool = True,
    max_iter: int = 30,
) -> _Fit:
    """Robust Gauss-Newton (IRLS, Cauchy loss) from ``st``, scale graduated down to the target."""
    fw = np.ones(p.n_frames) if frame_w is None else frame_w
    r, _ = _residuals(p, st)
    scale = loss_scale_px
    if anneal:
        med = float(np.median(np.linalg.norm(r, axis=1)))
        scale = float(np.clip(2.0 * med, loss_scale_px, 200.0))
    it = 0
    while True:
        r, jm = _residuals(p, st, jac=True, world=world, similarity=similarity, calib=calib)
        wgt = _cauchy_weights(r, scale) * fw[p.fidx]
        h, gvec = _normal_equations(jm, wgt, r)
        dg = np.diag(h).copy()
        if not np.all(dg > 0):
            return _Fit(st, wgt, r, jm, h, False)
        delta = -np.linalg.solve(h + 1e-9 * np.diag(dg), gvec)
        st = _update(p, st, delta, world, similarity, calib)
        it += 1
        small = np.max(np.abs(delta * np.sqrt(dg / max(wgt.sum(), 1.0)))) < 1e-4
        if scale > loss_scale_px:
            if small or it % 2 == 0:
                scale = max(loss_scale_px, scale / 2)
            continue
        if small or it >= max_iter:
            break
    r, jm = _residuals(p, st, jac=True, world=world, similarity=similarity, calib=calib)
    wgt = _cauchy_weights(r, scale) * fw[p.fidx]
    h, _ = _normal_equations(jm, wgt, r)
    d = np.sqrt(np.diag(h))
    ok = bool(np.all(d > 0))
    if ok:
        cond = np.linalg.cond(h / np.outer(d, d))
        ok = bool(np.isfinite(cond) and cond < 1e10)
    return _Fit(st, wgt, r, jm, h, ok)


def _max_canonical_corr(h: np.ndarray, a: np.ndarray, b: np.ndarray) -> float:
    """Largest canonical correlation between the estimates of column blocks a and b."""
    try:
        cov = np.linalg.inv(h)
    except np.linalg.LinAlgError:
        return 1.0
    caa, cbb, cab = cov[np.ix_(a, a)], cov[np.ix_(b, b)], cov[np.ix_(a, b)]

    def inv_sqrt(m: np.ndarray) -> np.ndarray:
        ev, vec = np.linalg.eigh(m)
        return vec @ np.diag(1 / np.sqrt(np.maximum(ev, 1e-300))) @ vec.T

    s = np.linalg.svd(inv_sqrt(caa) @ cab @ inv_sqrt(cbb), compute_uv=False)
    return float(min(1.0, s.max()))


# --------------------------------------------------------------------------------------------
# Bootstrap (one Gauss-Newton step per resample from the point estimate)
# --------------------------------------------------------------------------------------------


def _frame_blocks(p: _Problem, fit: _Fit) -> tuple[np.ndarray, np.ndarray]:
    """Per-frame normal-equation blocks H_f (F, P, P) and gradients g_f (F, P)."""
    jm, w, r = fit.jac, fit.weights, fit.residuals
    ends = np.append(p.starts[1:], len(r))
    blocks = [
        _normal_equations(jm[a:b], w[a:b], r[a:b]) for a, b in zip(p.starts, ends, strict=True)
    ]
    return np.stack([b[0] for b in blocks]), np.stack([b[1] for b in blocks])


def _bootstrap_deltas(
    p: _Problem, fit: _Fit, n_boot: int, seed: int
) -> tuple[np.ndarray, np.ndarray]:
    """(B, F) frame counts and (B, P) parameter steps of frame-resampled refits."""
    rng = np.random.default_rng(seed)
    nf = p.n_frames
    counts = rng.multinomial(nf, np.full(nf, 1.0 / nf), size=n_boot).astype(np.float64)
    hf, gf = _frame_blocks(p, fit)
    npar = hf.shape[1]
    hb = (counts @ hf.reshape(nf, -1)).reshape(n_boot, npar, npar)
    gb = counts @ gf
    damp = 1e-9 * np.einsum("bii->bi", hb).max(axis=1) + 1e-300
    hb = hb + damp[:, None, None] * np.eye(npar)
    return counts, -np.linalg.solve(hb, gb[..., None])[..., 0]


def _ci(x: np.ndarray, axis: int = 0) -> np.ndarray:
    return np.percentile(x, [2.5, 97.5], axis=axis)


def _weighted_median(values: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Row-wise weighted median of (B, F) values with (B, F) non-negative weights."""
    order = np.argsort(values, axis=1)
    v = np.take_along_axis(values, order, axis=1)
    cw = np.cumsum(np.take_along_axis(weights, order, axis=1), axis=1)
    idx = np.argmax(cw >= 0.5 * cw[:, -1:], axis=1)
    return v[np.arange(len(v)), idx]


# --------------------------------------------------------------------------------------------
# Effects
# --------------------------------------------------------------------------------------------


def _effect_points(p: _Problem, inliers: np.ndarray) -> np.ndarray:
    """Points used for a frame's pixel effect: its inliers, or all its points if < 3 inliers."""
    n_in = np.bincount(p.fidx[inliers], minlength=p.n_frames)
    return inliers | (n_in[p.fidx] < 3)


def _project_world(
    p: _Problem, q: np.ndarray, sig: np.ndarray, tau: np.ndarray, sel: np.ndarray
) -> np.ndarray:
    """(B, n, 2) pixels of the selected points under B world maps D (no calibration)."""
    f = p.fidx[sel]
    y = p.y[sel]
    xw = sig[:, None, None] * (y @ q.transpose(0, 2, 1)) + tau[:, None, :] - p.centre[f]
    pix = _bmv((p.K @ p.rt)[f], xw)
    return pix[..., :2] / pix[..., 2:3]


def _per_frame_mean(p: _Problem, sel: np.ndarray, values: np.ndarray) -> np.ndarray:
    """(B, n) values of the selected points -> (B, F) per-frame means (NaN without points)."""
    f = p.fidx[sel]
    cnt = np.bincount(f, minlength=p.n_frames).astype(np.float64)
    m = np.zeros((len(f), p.n_frames))
    m[np.arange(len(f)), f] = 1.0
    with np.errstate(invalid="ignore", divide="ignore"):
        return (values @ m) / cnt


def _world_params(p: _Problem, st: _State, deltas: np.ndarray | None, similarity: bool):
    """(Q (B,3,3), sigma (B,), tau (B,3)) for the point estimate (B=1) or bootstrap states."""
    if deltas is None:
        return st.q[None], np.array([np.exp(st.log_sigma)]), st.tau[None]
    q = _rodrigues(deltas[:, 0:3]) @ st.q
    tau = st.tau + deltas[:, 3:6]
    ls = st.log_sigma + (deltas[:, 6] if similarity else 0.0)
    return q, np.exp(np.broadcast_to(ls, (len(deltas),))), tau


def _correction_summary(q, sig, tau):
    """Angle (deg), scale s, centroid translation t of C = D^-1 for batched world maps."""
    angle = _angle_deg(q)
    s = 1.0 / sig
    t = -np.einsum("bji,bj->bi", q, tau) * s[:, None]  # -Q^T tau / sigma
    return angle, s, t


# --------------------------------------------------------------------------------------------
# Public estimators
# --------------------------------------------------------------------------------------------


def _robust_cost(fit: _Fit, scale: float) -> float:
    """Sum over points of log(1 + |r|^2 / scale^2) (the Cauchy cost, unit frame weights)."""
    return float(np.sum(np.log1p(np.sum(fit.residuals**2, axis=1) / scale**2)))


def _prefer_larger(small: _Fit, large: _Fit, n_extra: int, scale: float, penalty: float) -> bool:
    """BIC-like test: does the model with ``n_extra`` more parameters lower the robust cost by
    more than ``penalty * n_extra * log(n_inliers) * noise^2 / scale^2``? (In the Gaussian
    limit the Cauchy cost is |r|^2 / scale^2, so this is BIC scaled by ``penalty``.)"""
    rn2 = np.sum(large.residuals**2, axis=1)
    inl = rn2 < (3 * scale) ** 2
    if inl.sum() < 10:
        return False
    noise2 = float(np.median(rn2[inl]) / (2 * np.log(2)))  # 2D Gaussian: median |r|^2 = 2ln2 s^2
    gain = _robust_cost(small, scale) - _robust_cost(large, scale)
    return gain > penalty * n_extra * np.log(inl.sum()) * noise2 / scale**2


def _joint_fit(
    p: _Problem,
    *,
    similarity: bool,
    calibration: str,
    loss_scale_px: float,
    max_correlation: float,
    model_penalty: float = 2.0,
) -> tuple[_Fit, bool, bool, float]:
    """World fit, with per-camera calibration as nuisance when it is needed and separable.

    "auto": the joint fit is used when it lowers the robust cost significantly
    (``_prefer_larger``) and the blocks are separable (largest canonical correlation below
    ``max_correlation``); a significant but inseparable calibration gives the world-only fit
    marked ambiguous. Returns (fit, calibration fitted, ambiguous, largest canonical corr.).
    """
    st0 = _State.identity(p.n_cams)
    corr = float("nan")
    world_only = None
    if calibration != "joint":
        world_only = _solve(
            p, st0, world=True, similarity=similarity, calib=False, loss_scale_px=loss_scale_px
        )
        if calibration == "none":
            return world_only, False, False, corr
    if p.n_frames < 3:
        return world_only, False, False, corr
    fit = _solve(p, st0, world=True, similarity=similarity, calib=True, loss_scale_px=loss_scale_px)
    nw, off, _ = _layout(p, True, similarity, True)
    corrs = [
        _max_canonical_corr(fit.hessian, np.arange(nw), off + 4 * gi + np.arange(4))
        for gi in range(p.n_cams)
    ]
    corr = max(corrs) if fit.ok else 1.0
    if calibration == "joint":
        return fit, True, corr >= max_correlation, corr
    if not fit.ok or not _prefer_larger(
        world_only, fit, 4 * p.n_cams, loss_scale_px, model_penalty
    ):
        return world_only, False, corr >= max_correlation, corr
    if corr < max_correlation:
        return fit, True, False, corr
    return world_only, False, True, corr


def _registration_from_fit(
    p: _Problem,
    fit: _Fit,
    *,
    similarity: bool,
    calib: bool,
    n_bootstrap: int,
    seed: int,
    max_error_px: float,
    scene_depth: float | None,
    reference: _State | None = None,
    ambiguous: bool = False,
    corr: float = float("nan"),
    min_inliers: int = 12,
) -> RegistrationEstimate:
    """Summaries and bootstrap CIs of a world fit (relative to ``reference`` if given)."""
    st = fit.state
    rn = np.linalg.norm(fit.residuals, axis=1)
    inl = rn < max_error_px
    base = dict(
        n_frames=p.n_frames,
        n_points=len(rn),
        n_inliers=int(inl.sum()),
        frame_ids=p.frame_ids,
        similarity=similarity,
        calibration_fitted=calib,
        ambiguous_with_calibration=ambiguous,
        max_correlation=corr,
    )
    if not fit.ok:
        return RegistrationEstimate(False, "ill_conditioned", **base)
    if inl.sum() < min_inliers:
        return RegistrationEstimate(False, "too_few_inliers", **base)
    ref = reference if reference is not None else _State.identity(p.n_cams)
    # before: identity world map, fitted calibration kept (the world part alone is judged)
    st_before = _State(ref.q, ref.tau, ref.log_sigma, st.rcal, st.log_zoom)
    r_before, _ = _residuals(p, st_before)
    sel = _effect_points(p, inl)
    # depth of the selected points in the checked cameras
    zc = np.einsum("nj,nj->n", p.y[sel] - p.centre[p.fidx[sel]], p.rt[p.fidx[sel]][:, 2, :])
    depth = float(scene_depth) if scene_depth else float(np.median(zc))

    qr, sr, tr = _world_params(p, ref, None, similarity)
    u_ref = _project_world(p, qr, sr, tr, sel)[0]
    deltas = None
    counts = np.ones((1, p.n_frames))
    if n_bootstrap > 0:
        counts, deltas = _bootstrap_deltas(p, fit, n_bootstrap, seed)
    q0, s0, t0 = _world_params(p, st, None, similarity)
    qs, ss, ts = (q0, s0, t0) if deltas is None else _world_params(p, st, deltas, similarity)
    q_all = np.concatenate([q0, qs])
    s_all = np.concatenate([s0, ss])
    t_all = np.concatenate([t0, ts])
    u = _project_world(p, q_all, s_all, t_all, sel)
    eff_f = _per_frame_mean(p, sel, np.linalg.norm(u - u_ref[None], axis=2))  # (1+B, F)
    # relative map (reference^-1 then D): D_rel = D o D_ref^-1, as a correction C_rel
    q_rel = q_all @ qr[0].T
    s_rel = s_all / sr[0]
    t_rel = t_all - s_rel[:, None] * (tr[0] @ q_rel.transpose(0, 2, 1))
    angle, scale, trans = _correction_summary(q_rel, s_rel, t_rel)
    tnorm = np.linalg.norm(trans, axis=1)
    eff = np.concatenate(
        [
            [np.median(eff_f[0])],
            _weighted_median(eff_f[1:], counts) if deltas is not None else [],
        ]
    )

    def ci(x: np.ndarray) -> _CI:
        return tuple(_ci(x[1:]).tolist()) if deltas is not None else _NAN_CI

    # corrected_world_from_world = C = D^-1 (absolute, not relative to the reference)
    s_abs = 1.0 / s0[0]
    r_abs = q0[0].T
    t_abs = -(q0[0].T @ t0[0]) * s_abs
    c_mat = np.eye(4)
    c_mat[:3, :3] = s_abs * r_abs
    c_mat[:3, 3] = p.origin + t_abs - s_abs * r_abs @ p.origin
    return RegistrationEstimate(
        True,
        "",
        corrected_world_from_world=c_mat,
        angle_deg=float(angle[0]),
        angle_deg_ci=ci(angle),
        translation=float(tnorm[0]),
        translation_ci=ci(tnorm),
        translation_frac=float(tnorm[0] / depth),
        translation_frac_ci=ci(tnorm / depth),
        scale=float(scale[0]),
        scale_ci=ci(scale) if similarity else (1.0, 1.0),
        effect_px=float(eff[0]),
        effect_px_ci=ci(eff),
        effect_px_per_frame=eff_f[0],
        median_scene_depth=depth,
        residual_median_before=float(np.median(np.linalg.norm(r_before[inl], axis=1))),
        residual_median_after=float(np.median(rn[inl])),
        **base,
    )


def estimate_registration(
    evidence: Sequence[FrameEvidence],
    *,
    similarity: bool = False,
    calibration: str = "auto",
    n_bootstrap: int = 100,
    seed: int = 0,
    loss_scale_px: float = 2.0,
    max_error_px: float = 6.0,
    scene_depth: float | None = None,
    min_frames: int = 3,
    min_points_per_frame: int = 6,
    min_inliers: int = 30,
    max_correlation: float = 0.995,
    model_penalty: float = 2.0,
) -> RegistrationEstimate:
    """One world correction (rigid, or similarity) for the whole trajectory.

    calibration: "auto" (default) fits a per-camera camera-frame rotation + zoom jointly when it
    lowers the robust cost significantly (BIC-like test scaled by ``model_penalty``) and is
    separable from the world correction (largest canonical correlation < max_correlation);
    ``ambiguous_with_calibration`` is set whenever the blocks are not separable; "joint"
    always jointly; "none" never. loss_scale_px: Cauchy scale; max_error_px: inlier threshold. scene_depth:
    the depth used for ``translation_frac`` (default: median depth of the inliers).
    """
    p = _prepare(evidence, min_points_per_frame, min_frames)
    if isinstance(p, str):
        return RegistrationEstimate(False, p, n_frames=len(evidence), similarity=similarity)
    fit, calib, ambiguous, corr = _joint_fit(
        p,
        similarity=similarity,
        calibration=calibration,
        loss_scale_px=loss_scale_px,
        max_correlation=max_correlation,
        model_penalty=model_penalty,
    )
    if ambiguous:
        logger.info("registration: calibration not separable (corr %.3f); world-only fit", corr)
    return _registration_from_fit(
        p,
        fit,
        similarity=similarity,
        calib=calib,
        n_bootstrap=n_bootstrap,
        seed=seed,
        max_error_px=max_error_px,
        scene_depth=scene_depth,
        ambiguous=ambiguous,
        corr=corr,
        min_inliers=min_inliers,
    )


def estimate_calibration(
    evidence: Sequence[FrameEvidence],
    *,
    registration: str = "auto",
    n_bootstrap: int = 100,
    seed: int = 0,
    loss_scale_px: float = 2.0,
    max_error_px: float = 6.0,
    min_frames: int = 3,
    min_points_per_frame: int = 6,
    min_inliers: int = 30,
    max_correlation: float = 0.995,
    model_penalty: float = 2.0,
) -> dict[str, CalibrationEstimate]:
    """Per camera_id: shared camera-frame rotation (principal-point shift + roll) and zoom.

    registration: "auto" fits a rigid world correction jointly when it lowers the robust cost
    significantly (BIC-like, ``model_penalty``) and is separable; "joint" always; "none" never.
    ``separable`` is False when the largest canonical correlation between the calibration and
    the world blocks reaches ``max_correlation`` (a world error could look the same). Returns one
    estimate per camera id present in the evidence ({} when there is no evidence at all; a
    single "" entry with the reason when nothing usable remains).
    """
    p = _prepare(evidence, min_points_per_frame, min_frames)
    if isinstance(p, str):
        ids = sorted({ev.camera_id for ev in evidence}) or [""]
        return {cid: CalibrationEstimate(False, p, cid) for cid in ids}
    st0 = _State.identity(p.n_cams)
    corr = float("nan")
    fit = _solve(p, st0, world=False, similarity=False, calib=True, loss_scale_px=loss_scale_px)
    world = False
    separable = True
    if registration in ("auto", "joint"):
        joint = _solve(
            p, st0, world=True, similarity=False, calib=True, loss_scale_px=loss_scale_px
        )
        nw, off, _ = _layout(p, True, False, True)
        corr = (
            max(
                _max_canonical_corr(joint.hessian, np.arange(nw), off + 4 * g + np.arange(4))
                for g in range(p.n_cams)
            )
            if joint.ok
            else 1.0
        )
        needed = registration == "joint" or (
            joint.ok and _prefer_larger(fit, joint, 6, loss_scale_px, model_penalty)
        )
        separable = corr < max_correlation
        if needed and (separable or registration == "joint"):
            fit, world = joint, True
    out: dict[str, CalibrationEstimate] = {}
    rn = np.linalg.norm(fit.residuals, axis=1)
    inl = rn < max_error_px
    counts, deltas = (None, None)
    if n_bootstrap > 0 and fit.ok:
        counts, deltas = _bootstrap_deltas(p, fit, n_bootstrap, seed)
    nw, off, _ = _layout(p, world, False, True)
    sel = _effect_points(p, inl)
    st = fit.state
    for g, cid in enumerate(p.camera_ids):
        frames = np.flatnonzero(p.cam == g)
        pts = p.cam[p.fidx] == g
        base = dict(
            n_frames=len(frames),
            n_points=int(pts.sum()),
            n_inliers=int((inl & pts).sum()),
            separable=separable,
            max_correlation=corr,
            registration_fitted=world,
        )
        if not fit.ok:
            out[cid] = CalibrationEstimate(False, "ill_conditioned", cid, **base)
            continue
        if (inl & pts).sum() < min_inliers or len(frames) < min_frames:
            out[cid] = CalibrationEstimate(False, "too_few_inliers", cid, **base)
            continue
        rc = st.rcal[g][None]
        lz = np.array([st.log_zoom[g]])
        if deltas is not None:
            dc = deltas[:, off + 4 * g : off + 4 * g + 4]
            rc = np.concatenate([rc, _rodrigues(dc[:, :3]) @ st.rcal[g]])
            lz = np.concatenate([lz, st.log_zoom[g] + dc[:, 3]])
        rv = np.degrees(_rotvec(rc))  # (1+B, 3)
        kf = p.K[frames]
        fx, fy = float(np.median(kf[:, 0, 0])), float(np.median(kf[:, 1, 1]))
        # equivalent principal-point shift: image of the optical axis under the rotation
        ax = rc[:, :, 2]
        pp = np.stack([fx * ax[:, 0] / ax[:, 2], fy * ax[:, 1] / ax[:, 2]], axis=1)
        # pixel effect: displacement of the frame's points, checked projection -> calibrated
        sel_g = sel & pts
        u0 = _project_world(p, np.eye(3)[None], np.ones(1), np.zeros((1, 3)), sel_g)[0]
        fsel = p.fidx[sel_g]
        xc = _bmv(p.rt[fsel], p.y[sel_g] - p.centre[fsel])
        pix = (xc @ rc.transpose(0, 2, 1)) @ p.K[fsel[0]].T if len(fsel) else xc[None]
        if len(fsel) and not np.allclose(p.K[fsel], p.K[fsel[0]]):
            pix = _bmv(p.K[fsel], xc @ rc.transpose(0, 2, 1))
        cxy = p.K[fsel][:, :2, 2]
        u1 = cxy + np.exp(lz)[:, None, None] * (pix[..., :2] / pix[..., 2:3] - cxy)
        eff_f = _per_frame_mean(p, sel_g, np.linalg.norm(u1 - u0[None], axis=2))[:, frames]
        eff0 = float(np.median(eff_f[0]))
        ang = np.linalg.norm(rv, axis=1)
        has_boot = deltas is not None
        eff_b = _weighted_median(eff_f[1:], counts[:, frames]) if has_boot else None
        out[cid] = CalibrationEstimate(
            True,
            "",
            cid,
            rotation=rc[0],
            rotvec_deg=rv[0],
            rotvec_deg_ci=_ci(rv[1:]).T if has_boot else np.full((3, 2), np.nan),
            equivalent_rotation_deg=float(ang[0]),
            equivalent_rotation_deg_ci=tuple(_ci(ang[1:]).tolist()) if has_boot else _NAN_CI,
            principal_point_shift_px=pp[0],
            principal_point_shift_px_ci=_ci(pp[1:]).T if has_boot else np.full((2, 2), np.nan),
            roll_deg=float(rv[0, 2]),
            roll_deg_ci=tuple(_ci(rv[1:, 2]).tolist()) if has_boot else _NAN_CI,
            focal_scale=float(np.exp(lz[0])),
            focal_scale_ci=tuple(_ci(np.exp(lz[1:])).tolist()) if has_boot else _NAN_CI,
            effect_px=eff0,
            effect_px_ci=tuple(_ci(eff_b).tolist()) if has_boot else _NAN_CI,
            **base,
        )
    return out


def estimate_drift(
    evidence: Sequence[FrameEvidence],
    *,
    window: float = 0.2,
    step: float = 0.5,
    threshold_px: float = 2.0,
    similarity: bool = False,
    calibration: str = "auto",
    n_bootstrap: int = 100,
    seed: int = 0,
    loss_scale_px: float = 2.0,
    max_error_px: float = 6.0,
    min_frames: int = 4,
    min_points: int = 60,
    min_points_per_frame: int = 6,
) -> DriftEstimate:
    """Windowed world corrections along ``index`` relative to a reference registration.

    window: window length as a fraction of the index span; step: window step as a fraction of
    the window. The reference is the global fit (with calibration as in
    ``estimate_registration``); when windows are flagged it is refitted once on the unflagged
    frames, so a drifting segment does not bias what the rest is compared with. A frame is
    flagged when the interpolated lower 95 % bound of its window effects exceeds threshold_px.
    """
    p = _prepare(evidence, min_points_per_frame, 2 * min_frames)
    if isinstance(p, str):
        return DriftEstimate(False, p, threshold_px=threshold_px)
    fit, calib, ambiguous, corr = _joint_fit(
        p,
        similarity=similarity,
        calibration=calibration,
        loss_scale_px=loss_scale_px,
        max_correlation=0.995,
    )
    if not fit.ok:
        return DriftEstimate(False, "ill_conditioned", threshold_px=threshold_px)
    lo, hi = int(p.index.min()), int(p.index.max())
    span = hi - lo + 1
    length = max(1, int(round(window * span)))
    stride = max(1, int(round(step * length)))
    starts = list(range(lo, max(lo, hi - length + 1) + 1, stride))
    if starts[-1] + length <= hi:
        starts.append(hi - length + 1)

    def fit_windows(ref: _State) -> list:
        """World fits per window, calibration fixed at the reference's."""
        out = []
        for s in starts:
            frames = np.flatnonzero((p.index >= s) & (p.index < s + length))
            if len(frames) < min_frames:
                continue
            sub = _subset(p, frames)
            if len(sub.y) < min_points:
                continue
            wf = _solve(
                sub,
                ref,
                world=True,
                similarity=similarity,
                calib=False,
                loss_scale_px=loss_scale_px,
                anneal=True,
            )
            out.append((s, sub, wf))
        return out

    def evaluate(ref: _State):
        wins = []
        win_fits = fit_windows(ref)
        for s, sub, wf in win_fits:
            est = _registration_from_fit(
                sub,
                wf,
                similarity=similarity,
                calib=calib,
                n_bootstrap=n_bootstrap,
                seed=seed,
                max_error_px=max_error_px,
                scene_depth=None,
                reference=ref,
                min_inliers=min_points // 2,
            )
            wins.append(DriftWindow(s, s + length, est, est.success and est.exceeds(threshold_px)))
        ok = [w for w in wins if w.estimate.success]
        if not ok:
            return wins, None, None
        centres = np.array([(w.start + w.stop - 1) / 2 for w in ok])
        eff = np.array([w.estimate.effect_px for w in ok])
        low = np.array(
            [
                w.estimate.effect_px_ci[0]
                if np.isfinite(w.estimate.effect_px_ci[0])
                else w.estimate.effect_px
                for w in ok
            ]
        )
        return wins, np.interp(p.index, centres, eff), np.interp(p.index, centres, low)

    ref_state = fit.state
    wins, score, low = evaluate(ref_state)
    if score is None:
        return DriftEstimate(False, "too_few_points", threshold_px=threshold_px)
    flagged = low > threshold_px
    if flagged.any() and (~flagged).sum() >= 2 * min_frames:
        # refit the reference on the unflagged frames and compare again
        sub = _subset(p, np.flatnonzero(~flagged))
        rf = _solve(
            sub,
            fit.state,
            world=True,
            similarity=similarity,
            calib=calib,
            loss_scale_px=loss_scale_px,
            anneal=False,
        )
        if rf.ok:
            ref_state = rf.state
            wins, score, low = evaluate(ref_state)
            flagged = low > threshold_px
    r, jm = _residuals(p, ref_state, jac=True, world=True, similarity=similarity, calib=calib)
    wgt = _cauchy_weights(r, loss_scale_px)
    ref_fit = _Fit(ref_state, wgt, r, jm, _normal_equations(jm, wgt, r)[0], True)
    reference = _registration_from_fit(
        p,
        ref_fit,
        similarity=similarity,
        calib=calib,
        n_bootstrap=0,
        seed=seed,
        max_error_px=max_error_px,
        scene_depth=None,
        ambiguous=ambiguous,
        corr=corr,
    )
    segments = []
    i = 0
    while i < len(flagged):
        if flagged[i]:
            j = i
            while j + 1 < len(flagged) and flagged[j + 1]:
                j += 1
            segments.append((int(p.index[i]), int(p.index[j])))
            i = j + 1
        else:
            i += 1
    return DriftEstimate(
        True,
        "",
        reference=reference,
        windows=tuple(wins),
        frame_ids=p.frame_ids,
        frame_index=p.index.copy(),
        frame_score_px=score,
        frame_score_low_px=low,
        frame_flagged=flagged,
        segments=tuple(segments),
        threshold_px=threshold_px,
    )
