"""The shared camera-frame error (rotation = principal-point shift + roll, and zoom) per camera."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from pgt_check.geometry.shared_errors.effects import (
    _effect_points,
    _per_frame_mean,
    _project_world,
)
from pgt_check.geometry.shared_errors.evidence import FrameEvidence
from pgt_check.geometry.shared_errors.model import (
    _bmv,
    _layout,
    _prepare,
    _Problem,
    _rodrigues,
    _rotvec,
)
from pgt_check.geometry.shared_errors.results import _NAN_CI, CalibrationEstimate
from pgt_check.geometry.shared_errors.selection import _select, _Selection, _use_joint
from pgt_check.geometry.shared_errors.settings import CalibrationSettings
from pgt_check.geometry.shared_errors.solver import (
    _bootstrap_deltas,
    _ci,
    _Fit,
)


def _calibration_effect(
    p: _Problem, sel_g: np.ndarray, rc: np.ndarray, lz: np.ndarray, tc: np.ndarray
):
    """(B, F) per-frame mean displacement of the selected points of one camera, checked
    projection -> projection with camera rotations rc (B, 3, 3), log zooms lz (B,) and
    camera-frame translations tc (B, 3)."""
    u0 = _project_world(p, np.eye(3)[None], np.ones(1), np.zeros((1, 3)), sel_g)[0]
    fsel = p.fidx[sel_g]
    xc = _bmv(p.rt[fsel], p.y[sel_g] - p.centre[fsel])
    pix = _bmv(p.K[fsel], xc @ rc.transpose(0, 2, 1) + tc[:, None, :])
    cxy = p.K[fsel][:, :2, 2]
    u1 = cxy + np.exp(lz)[:, None, None] * (pix[..., :2] / pix[..., 2:3] - cxy)
    return _per_frame_mean(p, sel_g, np.linalg.norm(u1 - u0[None], axis=2))


def _camera_estimate(p, fit, g, cid, deltas, off, sel, base) -> CalibrationEstimate:
    """The estimate of camera group ``g`` from a successful fit (bootstrap steps optional)."""
    st = fit.state
    frames = np.flatnonzero(p.cam == g)
    rc = st.rcal[g][None]
    lz = np.array([st.log_zoom[g]])
    tc = st.tcal[g][None]
    if deltas is not None:
        n = p.n_cal
        dc = deltas[:, off + n * g : off + n * g + n]
        rc = np.concatenate([rc, _rodrigues(dc[:, :3]) @ st.rcal[g]])
        lz = np.concatenate([lz, st.log_zoom[g] + dc[:, 3]])
        dt = dc[:, 4:7] if n == 7 else np.zeros((len(dc), 3))
        tc = np.concatenate([tc, st.tcal[g] + dt])
    rv = np.degrees(_rotvec(rc))  # (1+B, 3)
    kf = p.K[frames]
    fx, fy = float(np.median(kf[:, 0, 0])), float(np.median(kf[:, 1, 1]))
    # equivalent principal-point shift: image of the optical axis under the rotation
    ax = rc[:, :, 2]
    pp = np.stack([fx * ax[:, 0] / ax[:, 2], fy * ax[:, 1] / ax[:, 2]], axis=1)
    eff_f = _calibration_effect(p, sel & (p.cam[p.fidx] == g), rc, lz, tc)[:, frames]
    ang = np.linalg.norm(rv, axis=1)
    boot = deltas is not None

    def ci(x: np.ndarray):
        return tuple(_ci(x).tolist()) if boot else _NAN_CI

    # the median over this camera's frames; the interval from the bootstrap states only (see
    # registration: re-drawing the frames of the median measures their spread, not precision)
    eff_b = np.nanmedian(eff_f[1:], axis=1) if boot else None
    return CalibrationEstimate(
        True,
        "",
        cid,
        rotation=rc[0],
        rotvec_deg=rv[0],
        rotvec_deg_ci=_ci(rv[1:]).T if boot else np.full((3, 2), np.nan),
        equivalent_rotation_deg=float(ang[0]),
        equivalent_rotation_deg_ci=ci(ang[1:]),
        principal_point_shift_px=pp[0],
        principal_point_shift_px_ci=_ci(pp[1:]).T if boot else np.full((2, 2), np.nan),
        roll_deg=float(rv[0, 2]),
        roll_deg_ci=ci(rv[1:, 2]),
        focal_scale=float(np.exp(lz[0])),
        focal_scale_ci=ci(np.exp(lz[1:])),
        translation=tc[0],
        translation_ci=_ci(tc[1:]).T if boot else np.full((3, 2), np.nan),
        translation_fitted=p.n_cal == 7,
        effect_px=float(np.median(eff_f[0])),
        effect_px_ci=ci(eff_b) if boot else _NAN_CI,  # type: ignore[arg-type]  # set with boot
        **base,
    )


def _camera_fields(
    p: _Problem, g: int, inl: np.ndarray, sel: _Selection, world: bool
) -> dict:
    """The counts of camera group ``g`` (``inl``: inlier mask over the points) and the fit
    choice, which every estimate of the camera reports."""
    frames = np.flatnonzero(p.cam == g)
    pts = p.cam[p.fidx] == g
    return dict(
        n_frames=len(frames), n_points=int(pts.sum()), n_inliers=int((inl & pts).sum()),
        separable=sel.separable, max_correlation=sel.corr, registration_fitted=world,
        ambiguity=sel.ambiguity, gain_world_only=sel.gain_world,
        gain_calibration_only=sel.gain_calib,
    )  # fmt: skip


def _choose_calibration_fit(
    p: _Problem, registration: str, scale: float, penalty: float, sel: _Selection
) -> tuple[_Fit, bool]:
    """(fit, world fitted jointly): "auto" uses the joint fit when it lowers the robust cost
    significantly over the calibration-only fit and the attribution is not ambiguous."""
    assert sel.joint is not None and sel.calib is not None  # ``_select`` fits all three
    if registration == "joint":
        return sel.joint, True
    if registration == "auto" and _use_joint(sel, sel.calib, 6, scale, penalty):
        return sel.joint, True
    return sel.calib, False


def estimate_calibration(
    evidence: Sequence[FrameEvidence],
    settings: CalibrationSettings | None = None,
    *,
    registration: str = "auto",
) -> dict[str, CalibrationEstimate]:
    """Per camera_id: shared camera-frame rotation (principal-point shift + roll) and zoom.

    settings: the robust-fit settings (``CalibrationSettings``; None: the defaults; with
    ``calibration_translation`` a camera-frame translation per camera is fitted too).
    registration: "auto" fits a rigid world correction jointly when it lowers the robust cost
    significantly (BIC-like, ``model_penalty``) and the attribution is not ambiguous; "joint"
    always; "none" never. ``separable`` is False (with the reason in ``ambiguity``) when a
    significant shared error could as well be a world registration error (see
    ``estimate_registration``); the estimate is then the calibration-only fit. Returns one
    estimate per camera id present in the evidence (a single "" entry with the reason when
    there is no evidence at all).
    """
    if registration not in ("auto", "joint", "none"):
        raise ValueError(f"registration must be auto, joint or none, not {registration!r}")
    s = settings if settings is not None else CalibrationSettings()
    p = _prepare(evidence, s.min_points_per_frame, s.min_frames, s.calibration_translation)
    if isinstance(p, str):
        ids = sorted({ev.camera_id for ev in evidence}) or [""]
        return {cid: CalibrationEstimate(False, p, cid) for cid in ids}
    sel = _select(
        p, similarity=False, loss_scale_px=s.loss_scale_px, max_correlation=s.max_correlation,
        model_penalty=s.model_penalty, ambiguity_margin=s.ambiguity_margin,
    )  # fmt: skip
    fit, world = _choose_calibration_fit(p, registration, s.loss_scale_px, s.model_penalty, sel)
    inl = np.linalg.norm(fit.residuals, axis=1) < s.max_error_px
    deltas = None
    if s.n_bootstrap > 0 and fit.ok:
        deltas = _bootstrap_deltas(p, fit, s.n_bootstrap, s.seed)[1]
    _, off, _ = _layout(p, world, False, True)
    sel_pts = _effect_points(p, inl)
    out: dict[str, CalibrationEstimate] = {}
    for g, cid in enumerate(p.camera_ids):
        base = _camera_fields(p, g, inl, sel, world)
        if not fit.ok:
            out[cid] = CalibrationEstimate(False, "ill_conditioned", cid, **base)
        elif base["n_inliers"] < s.min_inliers or base["n_frames"] < s.min_frames:
            out[cid] = CalibrationEstimate(False, "too_few_inliers", cid, **base)
        else:
            out[cid] = _camera_estimate(p, fit, g, cid, deltas, off, sel_pts, base)
    return out
