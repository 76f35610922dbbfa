"""The summary.json entries of the run-level checks (``verdict.shared``): each typed estimate of
``geometry.shared_errors`` becomes a status (passed / failed / inconclusive / not_checked, and
``finding`` for calibration) with its size, interval and a one-line message.

Statuses compare the 95 % interval of the image displacement with the threshold: ``failed`` when
its lower bound exceeds it, ``passed`` when its upper bound is below it (module docstring of
``verdict.shared``).
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Any

import numpy as np

from pgt_check.verdict.shared_results import (
    CalibrationCheck,
    DriftCheck,
    DriftFrame,
    FrameScreenCheck,
    LeftOutFrame,
    RegistrationCheck,
)
from pgt_check.verdict.status import FAILED, FINDING, INCONCLUSIVE, NOT_CHECKED, PASSED

__all__ = [
    "calibration_change_entry",
    "calibration_entry",
    "check_status",
    "coherent",
    "drift_entry",
    "finite_interval",
    "finite_or_none",
    "frame_screen_entry",
    "registration_entry",
    "shared_or_not",
    "trusted_allowance",
]


def finite_interval(x: Any) -> list[float] | None:
    if x is None:
        return None
    a = [float(v) for v in np.asarray(x, np.float64).reshape(-1)]
    return a if all(math.isfinite(v) for v in a) else None


def finite_or_none(x: Any) -> float | None:
    x = float(x)
    return x if math.isfinite(x) else None


def check_status(
    success: bool, effect_ci: Any, effect: float, threshold: float, allowance: float = 0.0
) -> str:
    """PASSED below ``threshold`` with confidence, FAILED above ``threshold + allowance`` with
    confidence, else INCONCLUSIVE. ``allowance``: an error the check cannot attribute (a
    trusted calibration that may carry its own run's misregistration, ``trusted_allowance``)."""
    if not success:
        return NOT_CHECKED
    lo, hi = effect_ci if finite_interval(effect_ci) else (effect, effect)
    if lo > threshold + allowance:
        return FAILED
    if hi <= threshold:
        return PASSED
    return INCONCLUSIVE


def registration_entry(
    est: Any, threshold: float, kind: str, allowance_px: float = 0.0
) -> RegistrationCheck:
    """The rigid or similarity check of a ``RegistrationEstimate`` (``kind``), with its
    message. ``allowance_px``: what a trusted calibration removed first may carry of its own
    run's misregistration (``trusted_allowance``): FAILED only above threshold + allowance."""
    status = check_status(est.success, est.effect_px_ci, est.effect_px, threshold, allowance_px)
    coherence_p = finite_or_none(est.coherence_p) if est.success else None
    if status == FAILED and not coherent(coherence_p, est.n_frames):
        status = INCONCLUSIVE
    check = RegistrationCheck(
        status=status,
        reason=est.reason,
        kind=kind,
        angle_deg=finite_or_none(est.angle_deg),
        angle_deg_ci=finite_interval(est.angle_deg_ci),
        translation=finite_or_none(est.translation),
        translation_ci=finite_interval(est.translation_ci),
        translation_rel_depth=finite_or_none(est.translation_frac),
        translation_rel_depth_ci=finite_interval(est.translation_frac_ci),
        scale=finite_or_none(est.scale),
        scale_ci=finite_interval(est.scale_ci),
        effect_px=finite_or_none(est.effect_px),
        effect_px_ci=finite_interval(est.effect_px_ci),
        n_frames=est.n_frames,
        n_points=est.n_points,
        n_inliers=est.n_inliers,
        coherence_p=coherence_p,
        allowance_px=float(allowance_px) if allowance_px > 0 else None,
        ambiguous_with_calibration=bool(est.ambiguous_with_calibration),
        corrected_world_from_world=(
            None
            if est.corrected_world_from_world is None
            else np.asarray(est.corrected_world_from_world).tolist()
        ),
    )
    return replace(check, message=registration_message(check, threshold))


def coherent(p_value: float | None, n_frames: int) -> bool:
    """Whether the frames pull together (``RegistrationEstimate.coherence_p`` at most
    ``COHERENCE_ALPHA``), or the test cannot tell (not run, or too few frames for its smallest
    p-value to reach the level: those runs keep the interval rule alone)."""
    from pgt_check.constants import COHERENCE_ALPHA
    from pgt_check.geometry.shared_errors import coherence_min_p

    if p_value is None or coherence_min_p(n_frames) > COHERENCE_ALPHA:
        return True
    return p_value <= COHERENCE_ALPHA


def registration_message(e: RegistrationCheck, threshold: float) -> str:
    """The one-line message of the registration check ``e`` (its ``message`` not yet set)."""
    what = "similarity" if e.kind == "similarity" else "rigid registration"
    if e.status == NOT_CHECKED:
        return (
            f"{what} of the trajectory to the mesh not checked: too little absolute "
            f"evidence ({e.reason or 'no frames'}; {e.n_frames} frames)"
        )
    lo, hi = e.effect_px_ci or (e.effect_px, e.effect_px)
    scale = f", scale {e.scale:.4f}" if e.kind == "similarity" else ""
    rel = e.translation_rel_depth
    nums = (
        f"{e.angle_deg:.2f} deg, {e.translation:.4g} scene units"
        + (f" ({100 * rel:.1f} % of the scene depth)" if rel is not None else "")
        + f"{scale}; moves the images by {e.effect_px:.1f} px (95 % {lo:.1f}-{hi:.1f}) "
        f"over {e.n_frames} frames"
    )
    verdict = {
        PASSED: f"passed: below {threshold:.1f} px",
        FAILED: f"FAILED: the trajectory is misregistered to the mesh (above {threshold:.1f} px)",
        INCONCLUSIVE: f"inconclusive: the interval straddles {threshold:.1f} px",
    }[e.status]
    if e.status == INCONCLUSIVE and lo is not None and lo > threshold:
        # above it, but the frames do not pull together (``coherent``), or within what a
        # trusted calibration may carry (``trusted_allowance``): the one that held it back
        if not coherent(e.coherence_p, e.n_frames):
            verdict = (f"inconclusive: above {threshold:.1f} px, but the frames do not pull "
                       f"together (sign-flip p = {e.coherence_p:.2g}): their own errors may "
                       "add up to it")
        elif e.allowance_px is not None:
            verdict = f"inconclusive: above {threshold:.1f} px, but {untold(e.allowance_px)}"
    amb = (
        " (not separable from a calibration error with these views)"
        if e.ambiguous_with_calibration
        else ""
    )
    return f"{what} {verdict}: correction {nums}{amb}"


def calibration_entry(
    est: Any, shared_thr: float, frame_thr: float, *, asserted: bool = False
) -> CalibrationCheck:
    """The calibration check of one camera's ``CalibrationEstimate``: FAILED only above the
    per-frame threshold ``frame_thr``, a FINDING between it and ``shared_thr``. ``asserted``
    (``--remove-calibration``): the user asserts the registration, so the estimate is the
    calibration even where the views cannot tell it from a registration error; the message
    says so (the ambiguity is reported, the estimate kept)."""
    status = check_status(est.success, est.effect_px_ci, est.effect_px, shared_thr)
    if status == FAILED:
        lo = (finite_interval(est.effect_px_ci) or [est.effect_px])[0]
        status = FAILED if lo > frame_thr else FINDING
    check = CalibrationCheck(
        status=status,
        reason=est.reason,
        effect_px=finite_or_none(est.effect_px),
        effect_px_ci=finite_interval(est.effect_px_ci),
        principal_point_shift_px=finite_interval(est.principal_point_shift_px),
        rotation_deg=finite_or_none(est.equivalent_rotation_deg),
        rotation_deg_ci=finite_interval(est.equivalent_rotation_deg_ci),
        roll_deg=finite_or_none(est.roll_deg),
        focal_scale=finite_or_none(est.focal_scale),
        focal_scale_ci=finite_interval(est.focal_scale_ci),
        n_frames=est.n_frames,
        separable_from_registration=bool(est.separable),
        # true_cam_from_checked_cam: what --calibration-from applies to another run
        rotation=None if est.rotation is None else np.asarray(est.rotation).tolist(),
        translation=finite_interval(est.translation) if est.translation_fitted else None,
        # (3, 2): the 95 % interval of each component
        translation_ci=(
            [finite_interval(row) for row in np.asarray(est.translation_ci)] if est.translation_fitted else None
        ),
    )
    if status == NOT_CHECKED:
        return replace(check, message=f"calibration not checked: no absolute evidence ({est.reason})")
    pp = check.principal_point_shift_px or [float("nan")] * 2
    message = (
        f"calibration {status}: every frame of this camera is displaced by "
        f"{est.effect_px:.1f} px: principal point off by ({pp[0]:+.1f}, {pp[1]:+.1f}) px or a "
        f"camera-to-rig rotation of {est.equivalent_rotation_deg:.2f} deg "
        f"(roll {est.roll_deg:+.2f} deg), focal length x{est.focal_scale:.4f}"
        + (
            ", camera-to-rig translation ({:+.4f}, {:+.4f}, {:+.4f}) scene units".format(
                *est.translation
            )
            if est.translation_fitted
            else ""
        )
        + ("" if est.separable else "; not separable from registration with these views")
        + (
            ", taken as calibration (--remove-calibration asserts the registration)"
            if asserted and not est.separable
            else ""
        )
    )
    return replace(check, message=message)


def trusted_allowance(trusted: Any, threshold: float, uncovered: float) -> float:
    """What a trusted calibration (``verdict.calibration.CameraCalibration``) may carry of its
    own run's misregistration that this run's views do not share, in px: none when that run
    told calibration from registration; else its shared threshold (``tolerance_px``; this
    run's ``threshold`` where the summary has none) times ``uncovered``, the share of this
    run's views the trusted run's do not cover (``verdict.calibration.uncovered_share``). A
    registration is known only to within that threshold when the run passes or the user
    asserts it (``--remove-calibration``), views that cannot tell the two apart put all of it
    into the calibration, and views the trusted run did not see need not share its offset (the
    segments of a 7-Scenes sweep differ by up to ~4 px, reports/trusted_subsets.md). Errors
    add, so a check run after removing it fails only above its threshold plus this. A trusted
    run over the same views (a moved copy of it, a run spread along the sweep) gives none: a
    moved trajectory still fails at the threshold."""
    if trusted is None or trusted.separable:
        return 0.0
    tol = float(trusted.tolerance_px)
    tol = tol if math.isfinite(tol) and tol > 0 else float(threshold)
    return tol * min(max(float(uncovered), 0.0), 1.0)


def untold(allowance_px: float) -> str:
    """The clause of a check held INCONCLUSIVE by ``trusted_allowance``."""
    return (
        f"within {allowance_px:.1f} px more, what the trusted calibration may carry of its own "
        "run's misregistration on views this run's do not share (that run could not tell the "
        "two apart; it is known only to within its shared threshold): calibrate on a run "
        "spread over the views this one sees to tell (docs/run-level-checks.md)"
    )


def calibration_change_entry(
    est: Any, threshold: float, trusted_separable: bool = True, allowance_px: float = 0.0
) -> CalibrationCheck:
    """This run's calibration against a trusted run's (``--calibration-from``): the estimate on
    the evidence after removing the trusted calibration. FAILED when it moves the images by
    more than the shared threshold with confidence: the camera changed (focal length,
    principal point, mounting) since the trusted run, and its frames are not PASS. With
    ``trusted_separable`` false (the trusted run could not tell this calibration from its own
    registration) a FAILED message also names the other explanation: the trusted estimate
    took in that run's own misregistration, and ``allowance_px`` (``trusted_allowance``) how
    much of it: FAILED only above threshold + allowance, INCONCLUSIVE between."""
    entry = calibration_entry(est, threshold, threshold)
    if entry.status == NOT_CHECKED:
        return replace(
            entry, message=f"calibration change not checked: no absolute evidence ({est.reason})"
        )
    status = check_status(est.success, est.effect_px_ci, est.effect_px, threshold, allowance_px)
    lo, hi = entry.effect_px_ci or (est.effect_px, est.effect_px)
    what = {
        FAILED: "calibration CHANGED since the trusted run",
        PASSED: "calibration as in the trusted run",
        INCONCLUSIVE: "calibration change since the trusted run inconclusive",
    }[status]
    pp = entry.principal_point_shift_px or [float("nan")] * 2
    message = (
        f"{what}: what is left moves the images by {est.effect_px:.1f} px (95 % {lo:.1f}-"
        f"{hi:.1f}, threshold {threshold:.1f}): principal point ({pp[0]:+.1f}, {pp[1]:+.1f}) px, "
        f"roll {est.roll_deg:+.2f} deg, focal length x{est.focal_scale:.4f}"
    )
    if status == INCONCLUSIVE and allowance_px > 0 and lo > threshold:
        message += f"; above {threshold:.1f} px, but {untold(allowance_px)}"
    elif status == FAILED and not trusted_separable:
        message += (
            "; or the trusted calibration took in part of the trusted run's own "
            "misregistration (that run could not tell the two apart): calibrate on a run "
            "spread over the views this one sees (docs/run-level-checks.md)"
        )
    return replace(entry, status=status, message=message,
                   allowance_px=float(allowance_px) if allowance_px > 0 else None)


def drift_coverage(
    est: Any, ids: list[str], threshold: float
) -> tuple[dict, dict, list[tuple[int, int]], set]:
    """Per trajectory frame (``ids``, trajectory order = ``FrameEvidence.index``): drift score
    and lower bound, and the flagged segments as (first, last) positions.

    Drift is a property of the trajectory segment, not of one frame's evidence: a frame without
    evidence of its own between the first and last frame with evidence gets the score
    interpolated along the trajectory; it is flagged when it lies in a flagged segment, and a
    segment grows over adjacent such frames whose interpolated lower bound exceeds the
    threshold. Returns (score, low, segments, ids with interpolated values)."""
    index = np.asarray(est.frame_index, np.float64)
    own = {fid: k for k, fid in enumerate(est.frame_ids)}
    score, low, interpolated = {}, {}, set()
    for i, fid in enumerate(ids):
        if fid in own:
            score[fid] = float(est.frame_score_px[own[fid]])
            low[fid] = float(est.frame_score_low_px[own[fid]])
        elif len(index) and index[0] <= i <= index[-1]:
            score[fid] = float(np.interp(i, index, est.frame_score_px))
            low[fid] = float(np.interp(i, index, est.frame_score_low_px))
            interpolated.add(fid)

    def grows(i: int) -> bool:
        return 0 <= i < len(ids) and ids[i] in interpolated and low[ids[i]] > threshold

    segments = []
    for a, b in est.segments:
        a, b = int(a), min(int(b), len(ids) - 1)
        while grows(a - 1):
            a -= 1
        while grows(b + 1):
            b += 1
        segments.append((a, b))
    return score, low, segments, interpolated


def drift_entry(
    est: Any, ids: list[str], threshold: float
) -> tuple[DriftCheck, dict[str, float], frozenset[str]]:
    """The drift check, the per-frame scores and the flagged frame ids; ``ids``: every frame of
    the run in trajectory order (with or without evidence)."""
    if not est.success:
        return (
            DriftCheck(NOT_CHECKED, est.reason, f"drift not checked ({est.reason})"),
            {},
            frozenset(),
        )
    score, low, runs, interpolated = drift_coverage(est, ids, threshold)
    own = {fid for fid, f in zip(est.frame_ids, est.frame_flagged, strict=True) if f}
    flagged = frozenset(own.union(*({ids[i] for i in range(a, b + 1)} for a, b in runs)))
    segments = tuple((ids[a], ids[b]) for a, b in runs)
    check = DriftCheck(
        status=FAILED if flagged else PASSED,
        reason=est.reason,
        threshold_px=threshold,
        segments=segments,
        n_windows=len(est.windows),
        per_frame=tuple(
            DriftFrame(
                frame_id=fid,
                index=i,
                effect_px=finite_or_none(score[fid]),
                lo_px=finite_or_none(low[fid]),
                flagged=fid in flagged,
                own_evidence=fid not in interpolated,
            )
            for i, fid in enumerate(ids)
            if fid in score
        ),
        message=(
            f"drift FAILED: {len(segments)} segment(s) move away from the mesh by more than "
            f"{threshold:.1f} px: " + ", ".join(f"{a} .. {b}" for a, b in segments)
            if flagged
            else f"drift passed: no window moves by more than {threshold:.1f} px"
        ),
    )
    return check, score, flagged


def shared_or_not(
    entry: RegistrationCheck, residuals: np.ndarray, tol_px: float
) -> RegistrationCheck:
    """``entry`` with ``frames_agreeing``: the share of the frames that agree with the
    correction (residual within ``tol_px`` after it). A FAILED entry becomes INCONCLUSIVE when
    fewer than half agree: the frames then carry errors of their own, and one shared
    correction does not describe them (e.g. 3 frames, 2 with large pose errors, which leaving
    frames out cannot separate)."""
    finite = residuals[np.isfinite(residuals)]
    agree = float(np.mean(finite <= tol_px)) if len(finite) else 0.0
    if entry.status != FAILED or agree >= 0.5:
        return replace(entry, frames_agreeing=agree)
    what = entry.message.split(" FAILED", 1)[0]
    return replace(
        entry,
        status=INCONCLUSIVE,
        message=(
            f"{what} inconclusive: only {agree:.0%} of the frames agree with one shared "
            f"correction (the others have errors of their own); the fitted one moves the "
            f"images by {entry.effect_px or float('nan'):.1f} px"
        ),
        frames_agreeing=agree,
    )


def frame_screen_entry(screen: Any) -> FrameScreenCheck:
    """The summary entry of the frames the run-level fits left out (a ``FrameScreen`` of
    ``geometry.shared_errors.screening``): how many, which, their own errors, and the rule's
    numbers (the cut is a multiple of the null spread the frames themselves show)."""
    if not screen.tested:
        return FrameScreenCheck(
            NOT_CHECKED, screen.reason,
            f"frames with errors of their own not tested ({screen.reason}): every frame with "
            "absolute evidence is pooled",
        )  # fmt: skip
    out = tuple(
        LeftOutFrame(f.frame_id, round(f.effect_px, 3), round(f.statistic / screen.cut, 3),
                     f.shared_with_neighbours)
        for f in screen.frames if f.left_out
    )  # fmt: skip
    n = len(screen.frames)
    rule = (
        f"own pose correction significant at {screen.alpha:.0%}: Wald statistic above "
        f"{screen.cut:.3g} = {screen.inflation:.3g} x the 99 % quantile of chi-square"
        f"({screen.dof:.1f})"
        + (f", or an image effect above {screen.effect_cut_px:.3g} px; each null"
           if np.isfinite(screen.effect_cut_px) else "; the null")
        + " fitted to the lower half of the frames' values"
    )
    eff_cut = finite_or_none(screen.effect_cut_px)
    if not out:
        return FrameScreenCheck(
            PASSED, "", f"run-level checks: all {n} frames with absolute evidence agree with "
            f"the shared model (none with an {rule})",
            n, 0, screen.inflation, screen.cut, screen.alpha, screen.dof, screen.chi2_quantile,
            screen.rounds, effect_cut_px=eff_cut,
        )  # fmt: skip
    errs = np.array([f.own_error_px for f in out])
    nb = sum(f.shared_with_neighbours for f in out)
    message = (
        f"run-level checks: {len(out)} of {n} frames left out of the pooled fits, their "
        f"absolute evidence disagrees with the shared model ({rule}); their own errors "
        f"{errs.min():.1f}-{errs.max():.1f} px (median {np.median(errs):.1f})"
        + (f"; {nb} of them kept for the drift check (their neighbours share the error)"
           if nb else "")
        + ("; more than half disagreed: the half that agrees best was kept"
           if screen.majority_kept else "")
    )
    return FrameScreenCheck(
        FINDING, "", message, n, len(out), screen.inflation, screen.cut, screen.alpha,
        screen.dof, screen.chi2_quantile, screen.rounds, screen.majority_kept, out, eff_cut,
    )  # fmt: skip
