"""The drift check: windows along the trajectory fitted to their frames' absolute evidence;
``failed`` where a segment moves away from the mesh by more than ``DRIFT_THRESHOLD_FACTOR`` x
the shared threshold. Frames with an isolated error of their own are left out (a drifting
segment's neighbours share its error); frames without evidence of their own are covered by
the segment they lie in. The entry keeps each frame's score and the flagged frames (the
verdicts read them through ``SharedChecks.drift_px`` / ``drift_flagged``)."""

from __future__ import annotations

from dataclasses import replace
from typing import Any

from pgt_check.constants import DRIFT_THRESHOLD_FACTOR
from pgt_check.verdict.checks.base import CheckContext, single_row, status_lines
from pgt_check.verdict.shared_results import DriftCheck

KEY = "drift"
TITLE = "drift"


def threshold(ctx: CheckContext) -> float:
    return DRIFT_THRESHOLD_FACTOR * ctx.threshold_px


def run(ctx: CheckContext) -> DriftCheck:
    entry, scores, flagged = ctx.drift  # computed once: the registration fits read it too
    return replace(entry, scores=scores, flagged_ids=flagged)


def lines(entry: Any) -> list[str]:
    return status_lines(entry)


def table(entry: Any) -> list[tuple[str, Any]]:
    return single_row(TITLE, entry)
