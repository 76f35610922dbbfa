"""What the verdict stage returns: ``RunResult``, the typed result of a run (one ``FrameResult``
per frame and the run-level ``SharedChecks``). The correction stage (``pgt_check.correct``)
takes it and returns it extended; only ``pgt_check.report`` turns it into rows and
summary.json sections (``row``, ``rows``)."""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from typing import Any

from pgt_check.measure.columns import headline_values
from pgt_check.measure.record import FrameMeasurement
from pgt_check.verdict.frame_bounds import FrameBound
from pgt_check.verdict.judgement import Judgement
from pgt_check.verdict.separation import Separation
from pgt_check.verdict.shared import SharedChecks

#: the verdict columns every row gets beside the measurement columns, with their meaning
VERDICT_COLUMNS: dict[str, str] = {
    "verdict": "PASS / FAIL / UNVERIFIABLE",
    "reason": "why (FAIL, UNVERIFIABLE)",
    "threshold_px": "PASS threshold on the corner error, photo px",
    "evidence": "what the verdict rests on: absolute, relative+registration, relative, none",
    "raw_verdict": "what the raw render alone says",
    "enhanced_verdict": "what the enhanced render alone says ('' if it did not run)",
    "disagree": "raw and enhanced paths give PASS and FAIL",
    "drift_px": "run-level drift score of this frame, px (see summary shared_errors.drift)",
    "decided_by": "the path the verdict rests on: raw, enhanced, edges ('' when none)",
}


@dataclass(frozen=True)
class FrameResult:
    """One judged frame: the measurement the verdict rests on (a vouched reference's when the
    verdict switched to it), its judgement, the frame's threshold, its run-level drift score
    and the pose accuracy its absolute evidence supports."""

    measurement: FrameMeasurement
    judgement: Judgement
    threshold_px: float
    drift_px: float | None = None
    bound: FrameBound = FrameBound()

    @property
    def frame_id(self) -> str:
        return self.measurement.frame_id

    @property
    def verdict(self) -> str:
        """"PASS", "FAIL" or "UNVERIFIABLE"."""
        return self.judgement.verdict.value

    @property
    def reason(self) -> str:
        return self.judgement.reason

    def row(self) -> dict[str, Any]:
        """The frame's frames.csv row (measurement columns + ``VERDICT_COLUMNS`` + the accuracy
        columns; the headline columns, ``measure.columns.HEADLINE_COLUMNS``, read from the path
        the verdict rests on) and ``camera_id`` (not a frames.csv column: calibrated_sensors.txt uses it)."""
        m, j = self.measurement, self.judgement
        row = m.row()
        if j.decided_by:
            # the headline columns are the deciding path's, its error as the verdict compared
            # it: a frame decided by the edge path never shows the enhanced path's error
            row.update(headline_values(m, j.decided_by))
            row["corner_error_px"] = j.error_px
        row.update(
            verdict=j.verdict.value,
            reason=j.reason,
            threshold_px=self.threshold_px,
            evidence=j.evidence,
            raw_verdict=j.raw_verdict,
            enhanced_verdict=j.enhanced_verdict,
            disagree=j.disagree,
            drift_px=self.drift_px,
            decided_by=j.decided_by,
        )
        row.update(self.bound.columns())
        row["camera_id"] = m.camera_id
        return row


@dataclass(frozen=True)
class RunResult:
    """The verdict stage's result: every frame's ``FrameResult`` (trajectory order) and the
    run-level checks (None when they were off or there were no frames)."""

    frames: tuple[FrameResult, ...]
    shared: SharedChecks | None
    #: each evidence path's separating power on this run (``verdict.separation``; None: not
    #: checked)
    separation: Separation | None = None

    @property
    def shared_as_reported(self) -> SharedChecks | None:
        """The run-level checks as reported (the correction stage's ``CorrectedRun`` refines a
        failed registration check's estimate)."""
        return self.shared

    def rows(self) -> list[dict[str, Any]]:
        """frames.csv rows (``row`` of each frame), for ``pgt_check.report`` and column-wise
        statistics over the run. Built once per result: the report panels, the accuracy
        statement and the outputs read the same list (none of them changes it)."""
        return self._rows

    @cached_property
    def _rows(self) -> list[dict[str, Any]]:
        return [self.row(f) for f in self.frames]

    def row(self, frame: FrameResult) -> dict[str, Any]:
        """One frame's row (``FrameResult.row``; a subclass adds its own columns)."""
        return frame.row()

    def summary_extra(self) -> dict[str, Any]:
        """summary.json's run-level section (``shared_errors``) and ``path_separation``."""
        out = {} if self.shared is None else {"shared_errors": self.shared.summary()}
        return {**out, **self.separation_extra()}

    def separation_extra(self) -> dict[str, Any]:
        """summary.json -> ``path_separation`` where the paths were checked."""
        if self.separation is None or not self.separation.paths:
            return {}
        return {"path_separation": self.separation.summary()}
