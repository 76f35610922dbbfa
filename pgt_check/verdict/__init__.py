"""Verdicts: per-frame PASS / FAIL / UNVERIFIABLE from measurements, and run-level statistics."""

from pgt_check.verdict.apply import VERDICT_COLUMNS, apply_verdicts
from pgt_check.verdict.decide import (
    Verdict,
    decide,
    gate,
    resolve_threshold_px,
    run_statistics,
    systematic_offset,
)

__all__ = [
    "VERDICT_COLUMNS",
    "Verdict",
    "apply_verdicts",
    "decide",
    "gate",
    "resolve_threshold_px",
    "run_statistics",
    "systematic_offset",
]
