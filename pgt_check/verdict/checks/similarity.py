"""The similarity registration check: as ``registration`` with a scale (a trajectory whose
scale is off, e.g. SLAM without metric scale)."""

from __future__ import annotations

from typing import Any

from pgt_check.verdict.checks.base import CheckContext, single_row, status_lines
from pgt_check.verdict.checks.registration import fit
from pgt_check.verdict.shared_results import RegistrationCheck

KEY = "similarity"
TITLE = "similarity (scale)"


def run(ctx: CheckContext) -> RegistrationCheck:
    return fit(ctx, similarity=True)


def lines(entry: Any) -> list[str]:
    return status_lines(entry)


def table(entry: Any) -> list[tuple[str, Any]]:
    return single_row(TITLE, entry)
