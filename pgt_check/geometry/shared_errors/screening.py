"""Frames with an error of their own, found by consensus before the run-level fits pool them.

A shared error is what most frames agree on. A frame whose pose carries an error of its own
(a bad frame among good ones) pulls a pooled fit by its own error divided by the number of
frames; with 40 % of the frames wrong in random directions that pull sums to several pixels
(more than the shared threshold), and a clean trajectory is reported as misregistered. A fixed
residual limit does not help: errors below the single-frame limit pull as well, and the noise
level of a frame's evidence differs from scene to scene.

The test is a significance test against a null estimated from the run itself:

1. one shared model (world similarity + per-camera calibration) is fitted robustly to the
   frames kept so far (all at first);
2. each frame's own correction is fitted to what that model leaves of its evidence: a small
   pose change (6 parameters, the world block's Jacobian restricted to the frame's points),
   by a few Cauchy-IRLS steps, with the frame's noise ``s^2`` estimated from its residuals
   after its own correction (median of ``|r|^2`` / (2 ln 2), a 2D Gaussian's);
3. its Wald statistic ``W = delta^T H delta / s^2`` is chi-square with 6 degrees of freedom
   when the frame agrees with the shared model and its points' errors are independent. They
   are not (neighbouring matches share texture, the mesh is not exact): that scales ``W`` and
   concentrates it in fewer directions (an offset every point of a frame shares is 2 of the 6),
   a heavier tail. So the null is fitted to the run as ``lambda * chi2_k``: ``k`` (1-2, see
   ``MAX_DOF``) from the spread of the logarithms of the LOWER HALF of all frames'
   statistics, ``lambda`` from their median (the null's quartile). With up to half of the frames wrong, and their statistics
   larger, the lower half is still a sample of the null (conservative when some are wrong);
4. a frame is left out when ``W > lambda * chi2_k^-1(1 - alpha)``; the model is refitted
   without it, until the set stops changing. A consensus needs a majority: when more than
   half of the frames would be left out, the half with the smallest statistics is kept
   (``majority_kept``).

So the cut adapts to the run: it is a multiple of the frames' own null spread, never a pixel
constant; on a clean run at most about ``alpha`` of the frames are left out (fewer where the
points' errors are independent: the 2-dof shape is conservative), at no cost but their
evidence in the pooled fits.

A frame left out whose own correction its neighbours in the trajectory share (``W`` of the
difference to a prediction from up to two neighbours on each side within the same cut: their
median, the mean of the adjacent two, or the line through two on one side, since a drift grows
along its segment), or within a tenth of its own statistic, is not an isolated error but
possibly a drifting segment: it is ``shared_with_neighbours`` and stays in the drift check's
evidence, which exists to find exactly that.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from pgt_check.geometry.shared_errors.evidence import FrameEvidence
from pgt_check.geometry.shared_errors.model import _prepare, _Problem, _residuals, _State
from pgt_check.geometry.shared_errors.settings import FitSettings
from pgt_check.geometry.shared_errors.solver import _cauchy_weights, _solve

#: degrees of freedom of a frame's own correction (a pose change)
OWN_DOF = 6
#: per-frame false-alarm rate of the test on a frame that agrees with the shared model
SCREEN_ALPHA = 0.01
#: the degrees of freedom of the fitted null (``_null``): between 1 and 2. With independent
#: point errors a frame's statistic is chi2_6, but an error every point of a frame shares (its
#: matches' texture, the mesh there) concentrates in 2 of the 6 directions, which the lower half
#: of the statistics does not show (it is floored by the independent part) while their tail
#: follows it: a 6-dof null fitted to 40 synthetic frames with 2 px of such error left out 9-17
#: correct frames. Taking at most 2 is conservative (the cut is up to 3.3x the chi2_6 quantile
#: in the statistic, 1.8x in pixels, on independent errors).
MIN_DOF, MAX_DOF = 1.0, 2.0
#: the cut on the image effect needs this many tested frames: its null is fitted to the lower
#: half (at least 10 values) and extrapolated to the 99 % quantile; on 12 frames of the clean
#: sample scene it left out 2 correct frames and the registration check of a re-check turned
#: inconclusive. Fewer frames: the Wald test alone
MIN_EFFECT_FRAMES = 20
#: neighbours on each side a left-out frame's own correction is compared with
NEIGHBOURS_PER_SIDE = 2
#: a left-out frame's error is shared with its neighbours when what they leave of it is within
#: the cut, or at most this fraction of its own statistic (a third of its size: a drift's
#: curvature between neighbours is significant on precise evidence, yet 0.01-0.06 of a
#: drifting frame's statistic on the synthetic segments; two random neighbours of a random
#: error predicted 0.22 of it)
NEIGHBOUR_SHARE = 0.1


@dataclass(frozen=True)
class ScreenedFrame:
    """One frame's test: its own correction's image effect (px, mean over its points), the
    Wald statistic, and the statistic of its difference to its neighbours' corrections."""

    frame_id: str
    effect_px: float
    statistic: float
    neighbour_statistic: float
    left_out: bool
    shared_with_neighbours: bool = False
    #: the image effect (px) of what its neighbours' corrections leave of its own
    neighbour_effect_px: float = float("inf")


@dataclass(frozen=True)
class FrameScreen:
    """The consensus of the run-level fits (module docstring). ``frames`` holds each frame
    with enough evidence to be tested; ``cut`` = ``inflation`` x ``chi2_quantile``."""

    tested: bool
    reason: str = ""
    frames: tuple[ScreenedFrame, ...] = ()
    inflation: float = float("nan")
    chi2_quantile: float = float("nan")
    cut: float = float("nan")
    alpha: float = SCREEN_ALPHA
    dof: float = OWN_DOF
    rounds: int = 0
    majority_kept: bool = False
    left_out: tuple[str, ...] = field(default=())
    #: the cut on a frame's own image effect (px; ``_effect_cut``; inf: not applied)
    effect_cut_px: float = float("inf")

    @property
    def isolated(self) -> tuple[str, ...]:
        """Left-out frames whose error their neighbours do not share (left out of drift too)."""
        return tuple(f.frame_id for f in self.frames if f.left_out and not f.shared_with_neighbours)

    def agreement(self) -> np.ndarray:
        """Per tested frame: the larger of statistic / cut and image effect / effect cut
        (<= 1: agrees with the shared model in both)."""
        return np.array([max(f.statistic / self.cut, f.effect_px / self.effect_cut_px)
                         for f in self.frames], np.float64)


def _chi2_ppf(q: float, dof: float) -> float:
    from scipy.stats import chi2

    return float(chi2.ppf(q, dof))


def _log_spread(dof: float) -> float:
    """Standard deviation of log chi2_dof over its lower half (its quantiles 0-50 %)."""
    from scipy.stats import chi2

    p = (np.arange(64) + 0.5) / 128
    return float(np.std(np.log(chi2.ppf(p, dof))))


def _null(stat: np.ndarray) -> tuple[float, float]:
    """(scale, degrees of freedom) of the null ``scale * chi2_dof`` fitted to the LOWER HALF of
    the frames' statistics (a sample of the null with up to half of the frames wrong, theirs
    larger): the degrees of freedom from the spread of their logarithms, clamped to
    [``MIN_DOF``, ``MAX_DOF``]; the scale from their median, the null's quartile."""
    low = np.sort(stat)[: max(3, (len(stat) + 1) // 2)]
    spread = float(np.std(np.log(np.maximum(low, 1e-300))))
    lo, hi = MIN_DOF, MAX_DOF
    if spread >= _log_spread(lo):
        dof = lo
    elif spread <= _log_spread(hi):
        dof = hi
    else:  # the spread falls with the degrees of freedom: bisection
        for _ in range(30):
            mid = 0.5 * (lo + hi)
            lo, hi = (mid, hi) if _log_spread(mid) > spread else (lo, mid)
        dof = 0.5 * (lo + hi)
    scale = float(np.median(low)) / _chi2_ppf(0.25, dof)
    return max(scale, 1e-12), dof


def _image_effect(j: np.ndarray, d: np.ndarray) -> float:
    """The image effect (px) of a pose change ``d`` (6,) on a frame's points: the mean length
    of ``j @ d``, ``j`` the points' image Jacobian (n, 2, 6)."""
    return float(np.mean(np.linalg.norm(j @ d, axis=1)))


def _effect_cut(eff: np.ndarray, alpha: float) -> float:
    """The cut on a frame's own image effect (px): ``sqrt(scale * chi2_k^-1(1 - alpha))`` with
    the null ``scale * chi2_k`` fitted to the squared effects like the statistics
    (``_null``: their lower half). The Wald test measures an error against the frame's own
    point noise; where the given poses themselves scatter from frame to frame more than their
    points do (7-Scenes' depth-camera poses: 0.3-2 deg), its null is inflated by the frames
    with many points, and a wrong frame with few points hides under it. The image effect of
    the frame's own correction is what the run-level fits are pulled by, and the frames'
    spread of it is the scene's pose noise: a frame far out in it is left out as well."""
    lam, dof = _null(np.maximum(eff, 1e-9) ** 2)
    return float(np.sqrt(lam * _chi2_ppf(1.0 - alpha, dof)))


def _shared_fit(p: _Problem, fw: np.ndarray, loss_scale_px: float):
    """The shared model on the frames with weight 1: similarity + calibration, or less where
    that is ill-conditioned (few frames or cameras)."""
    st0 = _State.identity(p.n_cams)
    for sim, cal in ((True, True), (False, True), (True, False), (False, False)):
        fit = _solve(p, st0, world=True, similarity=sim, calib=cal, loss_scale_px=loss_scale_px,
                     frame_w=fw)
        if fit.ok:
            return fit
    return None


def _own_corrections(p: _Problem, st: _State, loss_scale_px: float, iters: int = 4):
    """Per frame: own correction delta (F, 6), its Hessian H (F, 6, 6), the noise variance per
    coordinate s2 (F,), the Wald statistic (F,), the mean image effect (F,) px and the image
    Jacobian of its points (F arrays (n, 2, 6))."""
    r, jm = _residuals(p, st, jac=True, world=True, similarity=False, calib=False)
    assert jm is not None
    ends = np.append(p.starts[1:], len(r))
    nf = p.n_frames
    deltas, hs = np.zeros((nf, OWN_DOF)), np.zeros((nf, OWN_DOF, OWN_DOF))
    s2, stat, eff = np.zeros(nf), np.zeros(nf), np.zeros(nf)
    jacs = []
    for f, (a, b) in enumerate(zip(p.starts, ends, strict=True)):
        j, rr = jm[a:b], r[a:b]
        jf = j.reshape(-1, OWN_DOF)
        d = np.zeros(OWN_DOF)
        for _ in range(iters):
            ro = rr + j @ d
            n2 = np.sum(ro * ro, axis=1)
            noise = float(np.sqrt(np.median(n2) / (2 * np.log(2))))
            w = np.repeat(_cauchy_weights(ro, max(loss_scale_px, 2.0 * noise)), 2)
            h = jf.T @ (jf * w[:, None])
            g = jf.T @ (w * rr.reshape(-1))
            damp = 1e-9 * max(np.trace(h), 1e-300)
            d = -np.linalg.solve(h + damp * np.eye(OWN_DOF), g)
        ro = rr + j @ d
        s2[f] = max(float(np.median(np.sum(ro * ro, axis=1)) / (2 * np.log(2))), 1e-12)
        deltas[f], hs[f] = d, h
        stat[f] = float(d @ h @ d) / s2[f]
        eff[f] = _image_effect(j, d)
        jacs.append(j)
    return deltas, hs, s2, stat, eff, jacs


def _neighbour_predictions(p: _Problem, deltas: np.ndarray, f: int) -> list[np.ndarray]:
    """What frame ``f``'s own correction would be if its neighbours' error were shared along the
    trajectory: the component-wise median of up to ``NEIGHBOURS_PER_SIDE`` neighbours on each
    side, the mean of the two adjacent ones, and the straight lines (in trajectory position)
    through the two on either side (a drift grows along a segment; at its ends the lines
    extrapolate)."""
    k = NEIGHBOURS_PER_SIDE
    left = [i for i in range(f - k, f) if i >= 0]
    right = [i for i in range(f + 1, f + k + 1) if i < p.n_frames]
    out = []
    if left or right:
        out.append(np.median(deltas[left + right], axis=0))
    if left and right:
        out.append(0.5 * (deltas[left[-1]] + deltas[right[0]]))
    x = p.index.astype(np.float64)
    for a in (left[-2:], right[:2]):
        if len(a) == 2 and x[a[1]] != x[a[0]]:
            slope = (deltas[a[1]] - deltas[a[0]]) / (x[a[1]] - x[a[0]])
            out.append(deltas[a[0]] + slope * (x[f] - x[a[0]]))
    return out


def _neighbour_statistic(p: _Problem, deltas, hs, s2, jacs) -> tuple[np.ndarray, np.ndarray]:
    """Per frame: the smallest Wald statistic and the smallest image effect (px, mean over its
    points) of its own correction minus a prediction from its neighbours'
    (``_neighbour_predictions``; inf without neighbours)."""
    out, out_eff = np.full(p.n_frames, np.inf), np.full(p.n_frames, np.inf)
    for f in range(p.n_frames):
        for pred in _neighbour_predictions(p, deltas, f):
            diff = deltas[f] - pred
            out[f] = min(out[f], float(diff @ hs[f] @ diff) / s2[f])
            out_eff[f] = min(out_eff[f], _image_effect(jacs[f], diff))
    return out, out_eff


def screen_frames(
    evidence: Sequence[FrameEvidence],
    settings: FitSettings | None = None,
    *,
    alpha: float = SCREEN_ALPHA,
    max_rounds: int = 6,
) -> FrameScreen:
    """The frames whose evidence disagrees significantly with the shared model (module
    docstring); ``tested`` False (with ``reason``) when there are too few frames to test."""
    s = settings if settings is not None else FitSettings()
    p = _prepare(evidence, s.min_points_per_frame, max(s.min_frames, 4), s.calibration_translation)
    if isinstance(p, str):
        return FrameScreen(False, p)
    nf = p.n_frames
    kept = np.ones(nf, bool)
    lam, dof, q_null, majority, rounds = float("nan"), float(OWN_DOF), float("nan"), False, 0
    eff_cut = float("inf")
    stat = eff = nbs = None
    for rounds in range(1, max_rounds + 1):  # noqa: B007 (the count is reported)
        fit = _shared_fit(p, kept.astype(np.float64), s.loss_scale_px)
        if fit is None:
            return FrameScreen(False, "ill_conditioned")
        deltas, hs, s2, stat, eff, jacs = _own_corrections(p, fit.state, s.loss_scale_px)
        lam, dof = _null(stat)
        q_null = _chi2_ppf(1.0 - alpha, dof)
        eff_cut = _effect_cut(eff, alpha) if nf >= MIN_EFFECT_FRAMES else float("inf")
        new = (stat <= lam * q_null) & (eff <= eff_cut)
        majority = int(new.sum()) < (nf + 1) // 2
        if majority:
            new = np.zeros(nf, bool)
            new[np.argsort(stat, kind="stable")[: (nf + 1) // 2]] = True
        if np.array_equal(new, kept):  # round 1: none left out, the fit used them all
            break
        kept = new
    assert stat is not None and eff is not None  # max_rounds >= 1
    nbs, nb_eff = _neighbour_statistic(p, deltas, hs, s2, jacs)
    cut = lam * q_null
    # shared with its neighbours in either measure: what they leave of the frame's own
    # correction is within the cut, or a small part of it (NEIGHBOUR_SHARE of the statistic,
    # its square root of the image effect); an isolated frame is left out of the drift check
    # too, so the doubt goes to the drift check, which exists to find shared errors
    shared = (nbs <= np.maximum(cut, NEIGHBOUR_SHARE * stat)) | (
        np.isfinite(eff_cut) & (nb_eff <= np.maximum(eff_cut, np.sqrt(NEIGHBOUR_SHARE) * eff))
    )
    frames = tuple(
        ScreenedFrame(
            fid, float(eff[f]), float(stat[f]), float(nbs[f]), not bool(kept[f]),
            shared_with_neighbours=bool(not kept[f] and shared[f]),
            neighbour_effect_px=float(nb_eff[f]),
        )
        for f, fid in enumerate(p.frame_ids)
    )
    return FrameScreen(
        True, "", frames, lam, q_null, cut, alpha, dof, rounds, majority,
        tuple(f.frame_id for f in frames if f.left_out), eff_cut,
    )
