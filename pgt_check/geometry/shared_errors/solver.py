"""Robust Gauss-Newton (IRLS, Cauchy loss), separability, and the one-step frame bootstrap."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pgt_check.geometry.shared_errors.model import (
    _Problem,
    _residuals,
    _State,
    _update,
)


def _normal_equations(jm: np.ndarray, wgt: np.ndarray, r: np.ndarray):
    """H = J^T W J (P, P) and g = J^T W r (P,) for J (N, 2, P), weights (N,), r (N, 2)."""
    sw = np.sqrt(wgt)[:, None, None]
    jw = (jm * sw).reshape(-1, jm.shape[2])
    return jw.T @ jw, jw.T @ (r[:, :, None] * sw).reshape(-1)


def _start_scale(r: np.ndarray, loss_scale_px: float) -> float:
    """The Cauchy scale of a fit's first step on residuals ``r`` (N, 2): twice their median
    norm, at least ``loss_scale_px`` (the target) and at most 200 px."""
    med = float(np.median(np.linalg.norm(r, axis=1)))
    return float(np.clip(2.0 * med, loss_scale_px, 200.0))


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
        scale = _start_scale(r, loss_scale_px)
    it = 0
    while True:
        r, jm = _residuals(p, st, jac=True, world=world, similarity=similarity, calib=calib)
        assert jm is not None  # asked for
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
    assert jm is not None
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


def _frame_blocks(p: _Problem, fit: _Fit) -> tuple[np.ndarray, np.ndarray]:
    """Per-frame normal-equation blocks H_f (F, P, P) and gradients g_f (F, P) of a fit."""
    return _blocks_of(p, fit.jac, fit.weights, fit.residuals)


def _blocks_of(
    p: _Problem, jm: np.ndarray, w: np.ndarray, r: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Per-frame H_f (F, P, P) and g_f (F, P) of Jacobian ``jm``, weights ``w``, residuals ``r``."""
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


#: sign patterns drawn for the coherence test beyond ``COHERENCE_EXACT_FRAMES`` frames
COHERENCE_DRAWS = 2000
#: up to this many frames the coherence test enumerates every sign pattern (2^F, exact)
COHERENCE_EXACT_FRAMES = 12


def coherence_min_p(n_frames: int) -> float:
    """The smallest p-value ``_coherence_p`` can give with ``n_frames`` frames (a pattern and
    its opposite give the same statistic): with 5 frames or fewer it cannot reach 5 %."""
    if n_frames <= COHERENCE_EXACT_FRAMES:
        return 2.0 / 2.0 ** max(n_frames, 1)
    return 1.0 / (COHERENCE_DRAWS + 1)


def _coherence_p(
    p: _Problem, fit: _Fit, reference: _State, similarity: bool, loss_scale_px: float, seed: int
) -> float:
    """P-value of the null "no shared world error: each frame's pull is its own" for a fit.

    Sign-flip (randomisation) test at the frame level, on the linearisation at ``reference``'s
    world map (the fit's calibration kept): each frame's gradient g_f of the robust cost, its
    Cauchy weights from those residuals alone (scale as the fit's first step: twice their
    median, at least ``loss_scale_px``), so that a frame with its residuals' signs flipped
    weighs the same; weights taken from the fit would favour the data's own pattern. The
    statistic is the world block's efficient score ``dw' S dw`` of the one-step correction
    ``d = -H^-1 sum_f s_f g_f`` (``S``: the inverse of the world block of ``H^-1``, so the
    calibration stays a nuisance), every s_f = +1 for the data. Under the null the frames'
    errors are independent and symmetric, so flipping whole frames leaves the statistic's
    distribution unchanged; a shared error pulls every frame the same way and the flips break
    it. Every pattern up to ``COHERENCE_EXACT_FRAMES`` frames (the smallest p-value is then
    2 / 2^F), ``COHERENCE_DRAWS`` random ones beyond. Frames the fit left out (weight 0) add
    nothing. NaN when the blocks cannot be inverted."""
    import itertools

    n_world = 7 if similarity else 6
    calib = fit.jac.shape[2] > n_world
    r0, jm = _residuals(p, fit.state.with_world(reference), jac=True, world=True,
                        similarity=similarity, calib=calib)
    assert jm is not None  # asked for
    wgt = _cauchy_weights(r0, _start_scale(r0, loss_scale_px)) * (fit.weights > 0)
    hf, g = _blocks_of(p, jm, wgt, r0)
    h = hf.sum(axis=0)
    nf = p.n_frames
    if nf <= COHERENCE_EXACT_FRAMES:
        signs = np.array(list(itertools.product((1.0, -1.0), repeat=nf)))
    else:
        rng = np.random.default_rng(seed)
        signs = np.vstack([np.ones(nf), rng.choice((-1.0, 1.0), size=(COHERENCE_DRAWS, nf))])
    try:
        h_inv = np.linalg.inv(h + 1e-9 * np.diag(np.diag(h)))
        s_world = np.linalg.inv(h_inv[:n_world, :n_world])
    except np.linalg.LinAlgError:
        return float("nan")
    d_world = -(signs @ g) @ h_inv[:n_world].T  # (B, n_world): world part of -H^-1 g_s
    stat = np.einsum("bi,ij,bj->b", d_world, s_world, d_world)
    if not np.all(np.isfinite(stat)):
        return float("nan")
    return float(np.mean(stat >= stat[0] * (1.0 - 1e-9)))


def _ci(x: np.ndarray, axis: int = 0) -> np.ndarray:
    return np.percentile(x, [2.5, 97.5], axis=axis)


def _cost(r: np.ndarray, scale: float) -> float:
    """Sum over points of log(1 + |r|^2 / scale^2): the Cauchy cost of residuals (N, 2)."""
    return float(np.sum(np.log1p(np.sum(r * r, axis=1) / scale**2)))


def _robust_cost(fit: _Fit, scale: float) -> float:
    """The Cauchy cost of a fit's residuals (unit frame weights)."""
    return _cost(fit.residuals, scale)


def _penalty_unit(r: np.ndarray, scale: float) -> float:
    """Robust-cost price of one parameter: ``log(n_inliers) * noise^2 / scale^2`` (BIC in the
    Gaussian limit, where the Cauchy cost is |r|^2 / scale^2); inf with < 10 inliers."""
    rn2 = np.sum(r * r, axis=1)
    inl = rn2 < (3 * scale) ** 2
    if inl.sum() < 10:
        return float("inf")
    noise2 = float(np.median(rn2[inl]) / (2 * np.log(2)))  # 2D Gaussian: median |r|^2 = 2ln2 s^2
    return float(np.log(inl.sum()) * noise2 / scale**2)


def _prefer_larger(small: _Fit, large: _Fit, n_extra: int, scale: float, penalty: float) -> bool:
    """BIC-like test: does the model with ``n_extra`` more parameters lower the robust cost by
    more than ``penalty * n_extra * _penalty_unit``?"""
    gain = _robust_cost(small, scale) - _robust_cost(large, scale)
    return gain > penalty * n_extra * _penalty_unit(large.residuals, scale)


def _fit_at(
    p: _Problem, st: _State, *, world: bool, similarity: bool, calib: bool, scale: float
) -> _Fit:
    """A ``_Fit`` evaluated at a given state (no iterations), for CIs about that state."""
    r, jm = _residuals(p, st, jac=True, world=world, similarity=similarity, calib=calib)
    assert jm is not None
    wgt = _cauchy_weights(r, scale)
    return _Fit(st, wgt, r, jm, _normal_equations(jm, wgt, r)[0], True)
