"""The world correction (registration) of a whole trajectory or of one drift window."""

from __future__ import annotations

import logging
from collections.abc import Sequence

import numpy as np

from pgt_check.geometry.shared_errors.effects import (
    _correction_summary,
    _effect_points,
    _per_frame_mean,
    _project_world,
    _world_params,
)
from pgt_check.geometry.shared_errors.evidence import FrameEvidence
from pgt_check.geometry.shared_errors.model import _prepare, _Problem, _residuals, _State
from pgt_check.geometry.shared_errors.results import _CI, _NAN_CI, RegistrationEstimate
from pgt_check.geometry.shared_errors.selection import _select, _Selection, _use_joint
from pgt_check.geometry.shared_errors.settings import FitSettings
from pgt_check.geometry.shared_errors.solver import (
    _bootstrap_deltas,
    _ci,
    _coherence_p,
    _Fit,
    _solve,
)

logger = logging.getLogger(__name__)


def _batched(p: _Problem, st: _State, deltas: np.ndarray | None, similarity: bool):
    """World maps (Q, sigma, tau) with the point estimate first, then the bootstrap states."""
    q0, s0, t0 = _world_params(p, st, None, similarity)
    if deltas is None:
        return q0, s0, t0
    qs, ss, ts = _world_params(p, st, deltas, similarity)
    return np.concatenate([q0, qs]), np.concatenate([s0, ss]), np.concatenate([t0, ts])


def _relative(world, ref):
    """D_rel = D o D_ref^-1 for batched (Q, sigma, tau) of the fit and of the reference."""
    q_all, s_all, t_all = world
    qr, sr, tr = ref
    q_rel = q_all @ qr.transpose(0, 2, 1)
    s_rel = s_all / sr
    t_rel = t_all - s_rel[:, None] * np.einsum("bij,bj->bi", q_rel, tr)
    return q_rel, s_rel, t_rel


def _correction_matrix(p: _Problem, st: _State) -> np.ndarray:
    """corrected_world_from_world = C = D^-1 (absolute, in world coordinates)."""
    s_abs = 1.0 / np.exp(st.log_sigma)
    r_abs = st.q.T
    t_abs = -(st.q.T @ st.tau) * s_abs
    c_mat = np.eye(4)
    c_mat[:3, :3] = s_abs * r_abs
    c_mat[:3, 3] = p.origin + t_abs - s_abs * r_abs @ p.origin
    return c_mat


def _world_effects(p, fit, ref, sel, n_bootstrap, seed, similarity, ref_deltas):
    """Per-frame pixel effects (1+B, F), frame counts (B, F) and the relative corrections
    (angle, scale, translation) of the fit relative to ``ref`` (point estimate first). With
    ``ref_deltas`` (B, P_ref; world columns first) the reference is resampled too, paired with
    the fit's resamples, so the comparison carries the uncertainty of both."""
    deltas, counts = None, None
    if n_bootstrap > 0:
        counts, deltas = _bootstrap_deltas(p, fit, n_bootstrap, seed)
    world = _batched(p, fit.state, deltas, similarity)
    ref_b = _batched(p, ref, ref_deltas if deltas is not None else None, similarity)
    u_ref = _project_world(p, *ref_b, sel)
    u = _project_world(p, *world, sel)
    eff_f = _per_frame_mean(p, sel, np.linalg.norm(u - u_ref, axis=2))  # (1+B, F)
    angle, scale, trans = _correction_summary(*_relative(world, ref_b))
    return eff_f, counts, angle, scale, np.linalg.norm(trans, axis=1)


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
    ref_deltas: np.ndarray | None = None,
    selection: _Selection | None = None,
    min_inliers: int = 12,
    coherence: bool = False,
    loss_scale_px: float = 2.0,
) -> RegistrationEstimate:
    """Summaries and bootstrap CIs of a world fit (relative to ``reference`` if given); with
    ``coherence`` also the sign-flip p-value of its world part (``solver._coherence_p``)."""
    st = fit.state
    rn = np.linalg.norm(fit.residuals, axis=1)
    inl = rn < max_error_px
    base = _estimate_fields(p, rn, inl, similarity, calib, selection)
    if not fit.ok:
        return RegistrationEstimate(False, "ill_conditioned", **base)
    if inl.sum() < min_inliers:
        return RegistrationEstimate(False, "too_few_inliers", **base)
    ref = reference if reference is not None else _State.identity(p.n_cams)
    # before: the reference world map, fitted calibration kept (the world part alone is judged)
    r_before, _ = _residuals(p, st.with_world(ref))
    sel = _effect_points(p, inl)
    depth = _scene_depth(p, sel, scene_depth)
    eff_f, counts, angle, scale, tnorm = _world_effects(
        p, fit, ref, sel, n_bootstrap, seed, similarity, ref_deltas
    )
    has_boot = counts is not None
    eff = _median_effect(eff_f, has_boot)

    def ci(x: np.ndarray) -> _CI:
        return tuple(_ci(x[1:]).tolist()) if has_boot else _NAN_CI

    return RegistrationEstimate(
        True,
        "",
        corrected_world_from_world=_correction_matrix(p, st),
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
        coherence_p=(_coherence_p(p, fit, ref, similarity, loss_scale_px, seed) if coherence
                     else float("nan")),
        **base,
    )


def _estimate_fields(
    p: _Problem,
    rn: np.ndarray,
    inl: np.ndarray,
    similarity: bool,
    calib: bool,
    selection: _Selection | None,
) -> dict:
    """What every estimate reports, successful or not (rn: residual norms, inl: inlier mask)."""
    return dict(
        n_frames=p.n_frames, n_points=len(rn), n_inliers=int(inl.sum()), frame_ids=p.frame_ids,
        similarity=similarity, calibration_fitted=calib, **_selection_fields(selection),
    )  # fmt: skip


def _scene_depth(p: _Problem, sel: np.ndarray, scene_depth: float | None) -> float:
    """``scene_depth`` if given, else the median depth of the selected points (mask ``sel``)
    in the checked cameras."""
    zc = np.einsum("nj,nj->n", p.y[sel] - p.centre[p.fidx[sel]], p.rt[p.fidx[sel]][:, 2, :])
    return float(scene_depth) if scene_depth else float(np.median(zc))


def _median_effect(eff_f: np.ndarray, has_boot: bool) -> np.ndarray:
    """(1+B,) median over the frames of the per-frame effects eff_f (1+B, F); (1,) of the
    point estimate alone without bootstrap states."""
    # the effect is the median over THIS trajectory's frames; its interval comes from the
    # uncertainty of the correction (bootstrap states), not from re-drawing the frames for
    # the median: a similarity moves far frames more than near ones, and resampling which
    # frames enter the median measured that spread instead of the correction's precision
    return np.nanmedian(eff_f, axis=1) if has_boot else np.array([np.nanmedian(eff_f[0])])


def _selection_fields(sel: _Selection | None) -> dict:
    if sel is None:
        return {}
    return dict(
        ambiguous_with_calibration=sel.ambiguous,
        max_correlation=sel.corr,
        ambiguity=sel.ambiguity,
        gain_world_only=sel.gain_world,
        gain_calibration_only=sel.gain_calib,
    )


def _choose_world_fit(
    p: _Problem,
    *,
    similarity: bool,
    calibration: str,
    loss_scale_px: float,
    max_correlation: float,
    model_penalty: float,
    ambiguity_margin: float,
) -> tuple[_Fit, bool, _Selection | None]:
    """(fit, calibration fitted jointly, selection) for ``calibration`` in auto/joint/none.

    "auto": the joint fit when it lowers the robust cost significantly over the world-only fit
    and the attribution is not ambiguous; otherwise the world-only fit (so a misregistration is
    still measured when it could also be a calibration error, flagged as ambiguous)."""
    if calibration not in ("auto", "joint", "none"):
        raise ValueError(f"calibration must be auto, joint or none, not {calibration!r}")
    if calibration == "none" or p.n_frames < 3:
        st0 = _State.identity(p.n_cams)
        fit = _solve(
            p, st0, world=True, similarity=similarity, calib=False, loss_scale_px=loss_scale_px
        )
        return fit, False, None
    sel = _select(
        p, similarity=similarity, loss_scale_px=loss_scale_px, max_correlation=max_correlation,
        model_penalty=model_penalty, ambiguity_margin=ambiguity_margin,
    )  # fmt: skip
    assert sel.joint is not None and sel.world is not None  # ``_select`` fits all three
    if calibration == "joint":
        return sel.joint, True, sel
    if _use_joint(sel, sel.world, p.n_cal * p.n_cams, loss_scale_px, model_penalty):
        return sel.joint, True, sel
    return sel.world, False, sel


def estimate_registration(
    evidence: Sequence[FrameEvidence],
    settings: FitSettings | None = None,
    *,
    similarity: bool = False,
    calibration: str = "auto",
    scene_depth: float | None = None,
) -> RegistrationEstimate:
    """One world correction (rigid, or similarity) for the whole trajectory.

    settings: the robust-fit settings (``FitSettings``; None: the defaults).
    calibration: "auto" (default) fits a per-camera camera-frame rotation + zoom jointly when it
    lowers the robust cost significantly (BIC-like test scaled by ``model_penalty``) and the
    attribution is not ambiguous; "joint" always jointly; "none" never (no ambiguity check).
    ``ambiguous_with_calibration`` (with the reason in ``ambiguity``) is set when a significant
    shared error could as well be a calibration error: the blocks are not separable (largest
    canonical correlation >= ``max_correlation``) or world-only and calibration-only fits
    explain it about equally well (costs within ``ambiguity_margin`` of the larger cost drop);
    the estimate is then the world-only fit, so a misregistered trajectory is still caught.
    scene_depth: the depth used for ``translation_frac`` (default: median depth of the inliers).
    """
    s = settings if settings is not None else FitSettings()
    p = _prepare(evidence, s.min_points_per_frame, s.min_frames, s.calibration_translation)
    if isinstance(p, str):
        return RegistrationEstimate(False, p, n_frames=len(evidence), similarity=similarity)
    fit, calib, sel = _choose_world_fit(
        p, similarity=similarity, calibration=calibration, loss_scale_px=s.loss_scale_px,
        max_correlation=s.max_correlation, model_penalty=s.model_penalty,
        ambiguity_margin=s.ambiguity_margin,
    )  # fmt: skip
    if sel is not None and sel.ambiguous:
        logger.info("registration: %s; world-only fit reported", sel.ambiguity)
    return _registration_from_fit(
        p, fit, similarity=similarity, calib=calib, n_bootstrap=s.n_bootstrap, seed=s.seed,
        max_error_px=s.max_error_px, scene_depth=scene_depth, selection=sel,
        min_inliers=s.min_inliers, coherence=s.coherence, loss_scale_px=s.loss_scale_px,
    )  # fmt: skip
