"""The rigid registration check: one rigid world correction fitted to every frame's pooled
absolute evidence (frames with an error of their own left out); ``failed`` when it moves the
images by more than the shared threshold with confidence."""

from __future__ import annotations

from dataclasses import replace
from typing import Any

from pgt_check.verdict.checks.base import CheckContext, frame_residuals, single_row, status_lines
from pgt_check.verdict.shared_entries import registration_entry, shared_or_not
from pgt_check.verdict.shared_results import RegistrationCheck
from pgt_check.verdict.status import FAILED, NOT_CHECKED

KEY = "registration"
TITLE = "registration"


def _fit_on(ctx: CheckContext, ev: list[Any], similarity: bool) -> RegistrationCheck:
    from pgt_check.geometry import shared_errors as se

    est = se.estimate_registration(
        ev, se.FitSettings(calibration_translation=ctx.translation),
        similarity=similarity, calibration=ctx.mode,
    )  # fmt: skip
    entry = registration_entry(est, ctx.threshold_px, "similarity" if similarity else "rigid",
                               ctx.allowance_px)
    agree = ctx.agreement_of(ev) or (frame_residuals(ev, est), ctx.own_error_px)
    return shared_or_not(entry, *agree)


#: appended to a FAILED registration under ``--remove-calibration`` without a fitted translation
TRANSLATION_HINT = (
    "; --remove-calibration asserts the registration, so this may be what a rotation-and-zoom "
    "calibration cannot express: a camera beside the posed sensor (RGB beside depth) moves near "
    "points more than far ones; try --calibration-translation (docs/run-level-checks.md)"
)


def _hinted(ctx: CheckContext, entry: RegistrationCheck) -> RegistrationCheck:
    """``entry`` with ``TRANSLATION_HINT`` where it FAILED on evidence from which the asserted
    calibration was removed without a translation (measured: a trusted 7-Scenes segment whose
    RGB camera sits 2.5 cm beside the posed depth camera fails it at 3.8 px, and passes with
    the translation, reports/trusted_subsets.md)."""
    rc = ctx.config.run_checks
    if (entry.status == FAILED and rc.remove_calibration and not rc.calibration_from
            and not ctx.translation and ctx.removes_calibration):
        return replace(entry, message=entry.message + TRANSLATION_HINT)
    return entry


def fit(ctx: CheckContext, *, similarity: bool) -> RegistrationCheck:
    """The rigid (or, with ``similarity``, the similarity) registration entry: the fit, its
    status, the share of frames that agree with it and the frames left out. Where the drift
    check flagged a segment (``CheckContext.outside_drift``), the fit on the frames outside
    it, when it could be made."""
    outside = ctx.outside_drift
    if outside is not None:
        entry = _fit_on(ctx, outside, similarity)
        if entry.status != NOT_CHECKED:  # else too few outside: the pooled fit
            segment = {e.frame_id for e in ctx.fitted} - {e.frame_id for e in outside}
            return _hinted(ctx, replace(entry,
                                        frames_left_out=ctx.left_out + tuple(sorted(segment))))
    return _hinted(ctx, replace(_fit_on(ctx, ctx.fitted, similarity), frames_left_out=ctx.left_out))


def run(ctx: CheckContext) -> RegistrationCheck:
    return fit(ctx, similarity=False)


def lines(entry: Any) -> list[str]:
    return status_lines(entry)


def table(entry: Any) -> list[tuple[str, Any]]:
    return single_row(TITLE, entry)
