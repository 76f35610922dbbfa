"""Drift: windowed world corrections along the trajectory compared with the global one.

Windows of a nominal length (a fraction of the index span) grow about their centre until they
hold ``min_frames`` frames and ``min_window_inliers`` inliers of the reference fit, so sparse
evidence gives longer windows instead of noisy ones (on 20 real 7-Scenes frames, ~21 inliers
per frame, 4-frame windows with ~100 inliers scattered 1-3 px; with 150 inliers, 6-8 frames,
every window of the three test trajectories stays below 2 px). Each window's correction is
compared with the reference (global) one; both are bootstrapped over frames and paired, so the
95 % interval of the window effect carries the uncertainty of both. A window is flagged only
when the LOWER bound of that interval exceeds the threshold; of its frames, only those whose
evidence the window's correction explains better than the reference are counted (a drift moves
its frames together; frames beside it that the correction moves further off are not drifting).
A run of flagged frames is reported as a segment only when it spans ``min_segment_windows``
flagged windows or ``min_segment_frames`` frames.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from pgt_check.geometry.shared_errors.evidence import FrameEvidence
from pgt_check.geometry.shared_errors.model import (
    _prepare,
    _Problem,
    _residuals,
    _State,
    _subset,
)
from pgt_check.geometry.shared_errors.registration import (
    _choose_world_fit,
    _registration_from_fit,
)
from pgt_check.geometry.shared_errors.results import DriftEstimate, DriftWindow
from pgt_check.geometry.shared_errors.selection import _Selection
from pgt_check.geometry.shared_errors.settings import DriftSettings
from pgt_check.geometry.shared_errors.solver import _bootstrap_deltas, _Fit, _fit_at, _solve


@dataclass(frozen=True)
class _DriftOptions:
    threshold_px: float
    similarity: bool
    n_bootstrap: int
    seed: int
    loss_scale_px: float
    max_error_px: float
    min_frames: int
    min_window_inliers: int
    min_segment_windows: int
    min_segment_frames: int
    min_inliers: int  # of the reference estimate


def _window_bounds(
    index: np.ndarray,
    inliers: np.ndarray,
    points: np.ndarray,
    length: int,
    stride: int,
    min_frames: int,
    min_inl: int,
    min_pts: int,
) -> list[tuple[int, int]]:
    """Frame-position ranges [a, b) of the windows: nominal ``length`` index units every
    ``stride``, each grown about its centre until it holds ``min_frames`` frames, ``min_inl``
    inliers and ``min_pts`` points; duplicates and windows that would need all frames are
    dropped."""
    lo, hi, nf = int(index[0]), int(index[-1]), len(index)
    starts = list(range(lo, max(lo, hi - length + 1) + 1, stride))
    if starts[-1] + length <= hi:
        starts.append(hi - length + 1)
    cum = np.concatenate([[0], np.cumsum(inliers)])
    cum_pts = np.concatenate([[0], np.cumsum(points)])

    def enough(a: int, b: int) -> bool:
        return (
            b - a >= min_frames
            and cum[b] - cum[a] >= min_inl
            and cum_pts[b] - cum_pts[a] >= min_pts
        )

    out: list[tuple[int, int]] = []
    for s in starts:
        a, b = int(np.searchsorted(index, s)), int(np.searchsorted(index, s + length))
        centre = s + (length - 1) / 2
        while not enough(a, b) and (a > 0 or b < nf):
            if a > 0 and (b >= nf or centre - index[a - 1] <= index[b] - centre):
                a -= 1
            else:
                b += 1
        if enough(a, b) and (a, b) != (0, nf) and (a, b) not in out:
            out.append((a, b))
    return out


def _reference(p: _Problem, st: _State, frames: np.ndarray | None, opt: _DriftOptions, calib):
    """The reference fit (refitted on ``frames`` when given) and its bootstrap steps."""
    if frames is not None:
        sub = _subset(p, frames)
        rf = _solve(
            sub, st, world=True, similarity=opt.similarity, calib=calib,
            loss_scale_px=opt.loss_scale_px, anneal=False,
        )  # fmt: skip
        if not rf.ok:
            return None
        st = rf.state
    else:
        sub = p
        rf = _fit_at(
            p, st, world=True, similarity=opt.similarity, calib=calib, scale=opt.loss_scale_px
        )
    deltas = None
    if opt.n_bootstrap > 0:
        deltas = _bootstrap_deltas(sub, rf, opt.n_bootstrap, opt.seed)[1]
    return st, deltas


def _explained(sub: _Problem, wf: _Fit, ref: _State, similarity: bool) -> np.ndarray:
    """Per frame of a flagged window: does the window's correction explain it better than the
    reference (its median point residual smaller)? A drifting segment moves its frames together,
    so the window's correction fits them; a window pulled by frames with errors of their own
    (7-Scenes, 40 % wrong in runs of 2-4) moved the correct frames beside them 6-7 px further
    off, and those were flagged as drifting."""
    r_ref, _ = _residuals(sub, ref, world=True, similarity=similarity)
    e_w, e_r = np.linalg.norm(wf.residuals, axis=1), np.linalg.norm(r_ref, axis=1)
    return np.array([np.median(e_w[sub.fidx == f]) < np.median(e_r[sub.fidx == f])
                     for f in range(sub.n_frames)], bool)


def _evaluate(p: _Problem, bounds, ref: _State, ref_deltas, opt: _DriftOptions, calib: bool):
    """Window estimates relative to the reference, and per-frame interpolated effect, lower
    bound and flagged-window membership (None arrays when no window succeeds)."""
    wins = []
    member = np.zeros(p.n_frames, int)  # flagged windows holding each frame and explaining it
    for k, (a, b) in enumerate(bounds):
        sub = _subset(p, np.arange(a, b))
        wf = _solve(
            sub, ref, world=True, similarity=opt.similarity, calib=False,
            loss_scale_px=opt.loss_scale_px, anneal=True,
        )  # fmt: skip
        est = _registration_from_fit(
            sub, wf, similarity=opt.similarity, calib=calib, n_bootstrap=opt.n_bootstrap,
            seed=opt.seed + 1 + k, max_error_px=opt.max_error_px, scene_depth=None,
            reference=ref, ref_deltas=ref_deltas, min_inliers=opt.min_window_inliers // 2,
        )  # fmt: skip
        flagged = bool(est.success and est.exceeds(opt.threshold_px))
        if flagged:
            member[a:b] += _explained(sub, wf, ref, opt.similarity)
        wins.append(DriftWindow(int(p.index[a]), int(p.index[b - 1]) + 1, est, flagged))
    ok = [w for w in wins if w.estimate.success]
    if not ok:
        return wins, None, None, member
    centres = np.array([(w.start + w.stop - 1) / 2 for w in ok])
    eff = np.array([w.estimate.effect_px for w in ok])
    lows = [w.estimate.effect_px_ci[0] for w in ok]
    low = np.where(np.isfinite(lows), lows, eff)
    return wins, np.interp(p.index, centres, eff), np.interp(p.index, centres, low), member


def _segments(candidate: np.ndarray, member: np.ndarray, bounds, wins, opt: _DriftOptions):
    """Runs of candidate frames (positions); kept when long enough or spanning enough flagged
    windows. Returns (kept runs, rejected runs) as lists of (first, last) positions."""
    kept: list[tuple[int, int]] = []
    rejected: list[tuple[int, int]] = []
    i, n = 0, len(candidate)
    while i < n:
        if not candidate[i]:
            i += 1
            continue
        j = i
        while j + 1 < n and candidate[j + 1]:
            j += 1
        n_win = sum(
            1 for (a, b), w in zip(bounds, wins, strict=True) if w.flagged and a <= j and b > i
        )
        long_enough = j - i + 1 >= opt.min_segment_frames or n_win >= opt.min_segment_windows
        (kept if long_enough else rejected).append((i, j))
        i = j + 1
    return kept, rejected


def _flags(p, bounds, wins, low, member, opt):
    """(frame flags, kept segments, rejected segments) in trajectory indices."""
    candidate = (low > opt.threshold_px) & (member > 0)
    kept, rejected = _segments(candidate, member, bounds, wins, opt)
    flagged = np.zeros(p.n_frames, bool)
    for i, j in kept:
        flagged[i : j + 1] = True

    def idx(runs):
        return tuple((int(p.index[i]), int(p.index[j])) for i, j in runs)

    return flagged, idx(kept), idx(rejected)


def _compare(p: _Problem, bounds, ref: _State, ref_deltas, opt: _DriftOptions, calib: bool):
    """(windows, score, low, frame flags, segments, rejected segments), None without a
    successful window."""
    wins, score, low, member = _evaluate(p, bounds, ref, ref_deltas, opt, calib)
    if score is None:
        return None
    return (wins, score, low, *_flags(p, bounds, wins, low, member, opt))


def _reference_estimate(p: _Problem, st: _State, calib: bool, sel, opt: _DriftOptions):
    """The reference as a RegistrationEstimate over all frames (no bootstrap)."""
    fit = _fit_at(
        p, st, world=True, similarity=opt.similarity, calib=calib, scale=opt.loss_scale_px
    )
    return _registration_from_fit(
        p, fit, similarity=opt.similarity, calib=calib, n_bootstrap=0, seed=opt.seed,
        max_error_px=opt.max_error_px, scene_depth=None, selection=sel,
        min_inliers=opt.min_inliers,
    )  # fmt: skip


def _inliers_per_frame(p: _Problem, fit: _Fit, max_error_px: float) -> np.ndarray:
    inl = np.linalg.norm(fit.residuals, axis=1) < max_error_px
    return np.bincount(p.fidx[inl], minlength=p.n_frames)


def estimate_drift(
    evidence: Sequence[FrameEvidence],
    settings: DriftSettings | None = None,
    *,
    threshold_px: float = 2.0,
    similarity: bool = False,
    calibration: str = "auto",
) -> DriftEstimate:
    """Windowed world corrections along ``index`` relative to the reference registration.

    settings: ``DriftSettings`` (None: the defaults). window / step: nominal window length
    (fraction of the index span) and step (fraction of the window); windows grow about their
    centre to ``min_frames`` frames, ``min_window_inliers`` inliers and ``min_points`` points.
    The reference is the global fit (calibration as in ``estimate_registration``), refitted
    once on the unflagged frames when frames are flagged. A window is flagged when the lower
    95 % bound of its effect relative to the reference exceeds threshold_px; a frame when it
    lies in a flagged window, its interpolated lower bound exceeds threshold_px, and its run of
    such frames spans ``min_segment_windows`` flagged windows or ``min_segment_frames`` frames
    (shorter runs: ``rejected_segments``).
    """
    s = settings if settings is not None else DriftSettings()
    opt = _DriftOptions(
        threshold_px, similarity, s.n_bootstrap, s.seed, s.loss_scale_px, s.max_error_px,
        s.min_frames, s.min_window_inliers, s.min_segment_windows, s.min_segment_frames,
        s.min_inliers,
    )  # fmt: skip
    p = _prepare(evidence, s.min_points_per_frame, 2 * s.min_frames, s.calibration_translation)
    if isinstance(p, str):
        return DriftEstimate(False, p, threshold_px=threshold_px)
    fit, calib, sel = _choose_world_fit(
        p, similarity=similarity, calibration=calibration, loss_scale_px=s.loss_scale_px,
        max_correlation=s.max_correlation, model_penalty=s.model_penalty,
        ambiguity_margin=s.ambiguity_margin,
    )  # fmt: skip
    if not fit.ok:
        return DriftEstimate(False, "ill_conditioned", threshold_px=threshold_px)
    compared = _compare_windows(p, fit, calib, s.window, s.step, s.min_points, opt)
    if compared is None:
        return DriftEstimate(False, "too_few_inliers", threshold_px=threshold_px)
    return _drift_estimate(p, *compared, calib, sel, opt)


def _drift_bounds(
    p: _Problem, fit: _Fit, window: float, step: float, min_points: int, opt: _DriftOptions
) -> list[tuple[int, int]]:
    """The windows (``_window_bounds``) for a nominal ``window`` and ``step`` (fractions of the
    index span and of the window), grown to enough inliers of the reference ``fit``."""
    span = int(p.index[-1] - p.index[0]) + 1
    length = max(1, int(round(window * span)))
    inliers = _inliers_per_frame(p, fit, opt.max_error_px)
    points = np.bincount(p.fidx, minlength=p.n_frames)
    stride = max(1, int(round(step * length)))
    return _window_bounds(
        p.index, inliers, points, length, stride, opt.min_frames, opt.min_window_inliers,
        min_points,
    )  # fmt: skip


def _compare_windows(
    p: _Problem,
    fit: _Fit,
    calib: bool,
    window: float,
    step: float,
    min_points: int,
    opt: _DriftOptions,
) -> tuple[_State, list[tuple[int, int]], tuple] | None:
    """(reference state, window bounds, ``_compare`` result) with the reference refitted once
    on the unflagged frames when frames are flagged; None without a successful window."""
    bounds = _drift_bounds(p, fit, window, step, min_points, opt)
    if not bounds:
        return None
    ref_state, ref_deltas = _reference(p, fit.state, None, opt, calib)
    res = _compare(p, bounds, ref_state, ref_deltas, opt, calib)
    if res is None:
        return None
    if res[3].any() and (~res[3]).sum() >= 2 * opt.min_frames:
        # refit the reference on the unflagged frames and compare again
        ref = _reference(p, ref_state, np.flatnonzero(~res[3]), opt, calib)
        res2 = None if ref is None else _compare(p, bounds, ref[0], ref[1], opt, calib)
        if res2 is not None:
            ref_state, res = ref[0], res2
    return ref_state, bounds, res


def _drift_estimate(
    p: _Problem,
    ref_state: _State,
    bounds: list[tuple[int, int]],
    res: tuple,
    calib: bool,
    sel: _Selection | None,
    opt: _DriftOptions,
) -> DriftEstimate:
    """The successful estimate from the windows' comparison ``res`` (``_compare``)."""
    wins, score, low, flagged, segments, rejected = res
    return DriftEstimate(
        True,
        "",
        reference=_reference_estimate(p, ref_state, calib, sel, opt),
        windows=tuple(wins),
        frame_ids=p.frame_ids,
        frame_index=p.index.copy(),
        frame_score_px=score,
        frame_score_low_px=low,
        frame_flagged=flagged,
        segments=segments,
        rejected_segments=rejected,
        threshold_px=opt.threshold_px,
    )
