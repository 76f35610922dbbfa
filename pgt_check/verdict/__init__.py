"""Verdicts: per-frame PASS / FAIL / UNVERIFIABLE from measurements, and run-level statistics."""

from pgt_check.verdict.decide import (
    Verdict,
    decide,
    gate,
    resolve_threshold_px,
    run_statistics,
    systematic_offset,
)

__all__ = ["Verdict", "decide", "gate", "resolve_threshold_px", "run_statistics", "systematic_offset"]
