"""Which frames the pooled fits left out, and why (``shared_entries.frame_screen_entry``; the
rule: ``geometry.shared_errors.screening``): a ``finding`` when frames were left out."""

from __future__ import annotations

from typing import Any

from pgt_check.verdict.checks.base import CheckContext, single_row, status_lines
from pgt_check.verdict.shared_entries import frame_screen_entry
from pgt_check.verdict.shared_results import FrameScreenCheck

KEY = "frame_screen"
TITLE = "frames left out of the run-level fits"


def run(ctx: CheckContext) -> FrameScreenCheck:
    return frame_screen_entry(ctx.screen)


def lines(entry: Any) -> list[str]:
    return status_lines(entry)


def table(entry: Any) -> list[tuple[str, Any]]:
    return single_row(TITLE, entry)
