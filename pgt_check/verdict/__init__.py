"""Verdicts: per-frame PASS / FAIL / UNVERIFIABLE from measurements, and run-level statistics."""

from pgt_check.verdict.apply import apply_verdicts, judge_run
from pgt_check.verdict.decide import decide, judge, resolve_threshold_px
from pgt_check.verdict.judgement import Verdict
from pgt_check.verdict.result import VERDICT_COLUMNS, FrameResult, RunResult
from pgt_check.verdict.run_stats import gate, run_statistics, systematic_offset

__all__ = [
    "VERDICT_COLUMNS",
    "FrameResult",
    "RunResult",
    "judge_run",
    "Verdict",
    "apply_verdicts",
    "decide",
    "gate",
    "judge",
    "resolve_threshold_px",
    "run_statistics",
    "systematic_offset",
]
