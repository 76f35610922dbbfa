"""Statuses of the run-level checks (``summary.json`` -> ``shared_errors``)."""

from __future__ import annotations

PASSED, FAILED, INCONCLUSIVE, NOT_CHECKED, FINDING = (
    "passed",
    "failed",
    "inconclusive",
    "not_checked",
    "finding",
)
