"""The rigid registration check: one rigid world correction fitted to every frame's pooled
absolute evidence (frames with an error of their own left out); ``failed`` when it moves the
images by more than the shared threshold with confidence."""

from __future__ import annotations

from dataclasses import replace
from typing import Any

from pgt_check.verdict.checks.base import CheckContext, frame_residuals, single_row, status_lines
from pgt_check.verdict.shared_entries import registration_entry, shared_or_not
from pgt_check.verdict.shared_results import RegistrationCheck

KEY = "registration"
TITLE = "registration"


def fit(ctx: CheckContext, *, similarity: bool) -> RegistrationCheck:
    """The rigid (or, with ``similarity``, the similarity) registration entry: the fit, its
    status, the share of frames that agree with it and the frames left out."""
    from pgt_check.geometry import shared_errors as se

    est = se.estimate_registration(
        ctx.fitted, se.FitSettings(calibration_translation=ctx.translation),
        similarity=similarity, calibration=ctx.mode,
    )  # fmt: skip
    entry = registration_entry(est, ctx.threshold_px, "similarity" if similarity else "rigid")
    agree = ctx.agreement or (frame_residuals(ctx.fitted, est), ctx.own_error_px)
    return replace(shared_or_not(entry, *agree), frames_left_out=ctx.left_out)


def run(ctx: CheckContext) -> RegistrationCheck:
    return fit(ctx, similarity=False)


def lines(entry: Any) -> list[str]:
    return status_lines(entry)


def table(entry: Any) -> list[tuple[str, Any]]:
    return single_row(TITLE, entry)
