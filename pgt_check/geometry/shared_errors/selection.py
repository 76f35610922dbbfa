"""Model selection: world correction, per-camera calibration, or both, and when it is ambiguous.

Three fits from identity: world-only (6-7 parameters), calibration-only (4 per camera) and joint.
A shared error is *significant* when a single-block fit lowers the robust cost by more than its
BIC-like price. It is *ambiguous* (registration or calibration cannot be told apart) when it is
significant and either the blocks are not separable (largest canonical correlation of the joint
fit >= ``max_correlation``) or the world-only and calibration-only fits explain it about equally
well: their robust costs differ by less than ``ambiguity_margin`` of the larger cost drop, and at
least by less than the price of the calibration block (what the joint model must gain to be
adopted). On real 7-Scenes frames world-only and calibration-only explained the shared error
about equally well while the correlation stayed below the limit (reports/shared_errors.md).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pgt_check.geometry.shared_errors.model import _layout, _Problem, _residuals, _State
from pgt_check.geometry.shared_errors.solver import (
    _cost,
    _Fit,
    _max_canonical_corr,
    _penalty_unit,
    _prefer_larger,
    _robust_cost,
    _solve,
)


@dataclass(frozen=True, eq=False)
class _Selection:
    world: _Fit | None  # world-only fit (None when not computed)
    calib: _Fit | None  # calibration-only fit
    joint: _Fit | None  # joint fit
    corr: float  # largest canonical correlation world vs a camera block (nan: not computed)
    gain_world: float  # robust-cost drop of the world-only fit vs no correction
    gain_calib: float  # same for the calibration-only fit
    unit: float  # robust-cost price of one parameter
    ambiguous: bool
    ambiguity: str  # human-readable reason ("" when not ambiguous)

    @property
    def separable(self) -> bool:
        return not self.ambiguous


def _ambiguity(
    gain_w: float,
    gain_c: float,
    n_w: int,
    n_c: int,
    unit: float,
    corr: float,
    *,
    max_correlation: float,
    model_penalty: float,
    ambiguity_margin: float,
) -> str:
    """The reason a significant shared error cannot be attributed ("" when it can, or when
    there is no significant shared error)."""
    if not (gain_w > model_penalty * n_w * unit or gain_c > model_penalty * n_c * unit):
        return ""
    reasons = []
    if not corr < max_correlation:  # nan (joint fit failed) counts as inseparable
        reasons.append(
            f"world and camera-calibration parameters are not separable with this trajectory "
            f"(canonical correlation {corr:.3f} >= {max_correlation})"
        )
    margin = max(ambiguity_margin * max(gain_w, gain_c), model_penalty * n_c * unit)
    if abs(gain_w - gain_c) <= margin:
        reasons.append(
            f"world-only and calibration-only fits explain the shared error about equally well "
            f"(robust-cost drop {gain_w:.1f} vs {gain_c:.1f}, margin {margin:.1f})"
        )
    if not reasons:
        return ""
    return "; ".join(reasons) + ": it may be a registration or a calibration error"


def _select(
    p: _Problem,
    *,
    similarity: bool,
    loss_scale_px: float,
    max_correlation: float,
    model_penalty: float,
    ambiguity_margin: float,
) -> _Selection:
    """World-only, calibration-only and joint fits, and whether the attribution is ambiguous."""
    st0 = _State.identity(p.n_cams)
    fits = {}
    for name, world, calib in (("world", True, False), ("calib", False, True), ("joint", 1, 1)):
        fits[name] = _solve(
            p, st0, world=bool(world), similarity=similarity and bool(world), calib=bool(calib),
            loss_scale_px=loss_scale_px,
        )  # fmt: skip
    w, c, j = fits["world"], fits["calib"], fits["joint"]
    nw, off, _ = _layout(p, True, similarity, True)
    corr = float("nan")
    if j.ok:
        corr = max(
            _max_canonical_corr(
                j.hessian, np.arange(nw), off + p.n_cal * g + np.arange(p.n_cal)
            )
            for g in range(p.n_cams)
        )
    c0 = _cost(_residuals(p, st0)[0], loss_scale_px)
    gain_w = c0 - _robust_cost(w, loss_scale_px)
    gain_c = c0 - _robust_cost(c, loss_scale_px)
    best = j if j.ok else (w if gain_w >= gain_c else c)
    unit = _penalty_unit(best.residuals, loss_scale_px)
    reason = _ambiguity(
        gain_w, gain_c, nw, p.n_cal * p.n_cams, unit, corr,
        max_correlation=max_correlation, model_penalty=model_penalty,
        ambiguity_margin=ambiguity_margin,
    )  # fmt: skip
    return _Selection(w, c, j, corr, gain_w, gain_c, unit, bool(reason), reason)


def _use_joint(sel: _Selection, base: _Fit, n_extra: int, scale: float, penalty: float) -> bool:
    """Adopt the joint fit over ``base`` (a single-block fit): it lowers the robust cost
    significantly and the attribution is not ambiguous."""
    j = sel.joint
    if j is None or not j.ok or sel.ambiguous:
        return False
    return _prefer_larger(base, j, n_extra, scale, penalty)
