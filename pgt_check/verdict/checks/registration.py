"""The rigid registration check: one rigid world correction fitted to every frame's pooled
absolute evidence (frames with an error of their own left out); ``failed`` when it moves the
images by more than the shared threshold with confidence."""

from __future__ import annotations

from dataclasses import replace
from typing import Any

from pgt_check.verdict.checks.base import CheckContext, frame_residuals, single_row, status_lines
from pgt_check.verdict.shared_entries import registration_entry, shared_or_not
from pgt_check.verdict.shared_results import RegistrationCheck
from pgt_check.verdict.status import NOT_CHECKED

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
            return replace(entry, frames_left_out=ctx.left_out + tuple(sorted(segment)))
    return replace(_fit_on(ctx, ctx.fitted, similarity), frames_left_out=ctx.left_out)


def run(ctx: CheckContext) -> RegistrationCheck:
    return fit(ctx, similarity=False)


def lines(entry: Any) -> list[str]:
    return status_lines(entry)


def table(entry: Any) -> list[tuple[str, Any]]:
    return single_row(TITLE, entry)
