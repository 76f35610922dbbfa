"""What the correction stage returns: ``CorrectedRun``, the verdict stage's ``RunResult``
extended by what the corrections found. Only ``pgt_check.report`` serialises it."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from pgt_check.correct.calibration import CalibratedRig
from pgt_check.correct.correction import Correction
from pgt_check.correct.frames import CorrectionsSummary
from pgt_check.output_layout import OUTPUTS
from pgt_check.verdict.result import FrameResult, RunResult
from pgt_check.verdict.self_test_curves import SelfTest
from pgt_check.verdict.shared import SharedChecks


@dataclass(frozen=True)
class CorrectedRun(RunResult):
    """``RunResult`` (the frames' verdicts and the run-level checks they were judged with)
    plus the correction stage's findings: ``reported_shared``, the run-level checks as reported
    (a failed registration check's estimate refined; None: as judged), the calibration
    written as a rig, the corrected poses (frame id -> ``Correction``) and their summary, and
    the self-test of the stated limits when one ran."""

    reported_shared: SharedChecks | None = None
    calibrated_rig: CalibratedRig | None = None
    corrections: Mapping[str, Correction] = field(default_factory=dict)
    corrections_summary: CorrectionsSummary | None = None
    self_test: SelfTest | None = None

    @classmethod
    def of(cls, result: RunResult, **found: Any) -> CorrectedRun:
        """``result`` with the correction stage's ``found`` fields."""
        return cls(result.frames, result.shared, result.separation, **found)

    @property
    def shared_as_reported(self) -> SharedChecks | None:
        return self.reported_shared if self.reported_shared is not None else self.shared

    def row(self, frame: FrameResult) -> dict[str, Any]:
        """The frame's row with the correction columns where it was corrected (frames without
        a correction have none: empty cells)."""
        row, c = frame.row(), self.corrections.get(frame.frame_id)
        return {**row, **c.row()} if c is not None else row

    def summary_extra(self) -> dict[str, Any]:
        """summary.json's sections of the run-level checks (as reported) and the corrections."""
        shared = self.shared_as_reported
        out: dict[str, Any] = {} if shared is None else {"shared_errors": shared.summary()}
        out.update(self.separation_extra())
        if self.self_test is not None:
            out["self_test"] = self.self_test.to_json()
        if self.calibrated_rig is not None:
            out["calibrated_rig"] = self.calibrated_rig.to_json()
        if self.corrections_summary is not None:
            out["corrections"] = self.corrections_summary.to_json()
        return out


def stored_corrections(judged: RunResult, out: str | Path) -> tuple[CorrectedRun, bool]:
    """A new judgement of a run's stored measurements (``pgt-check report``, the API) with the
    run's stored corrections (``corrections.json``) and its registration refinement where it
    started from this judgement's estimate; and whether a refinement file was left out as
    stale (measured for another estimate: other verdict settings)."""
    from pgt_check.correct.correction import load_corrections
    from pgt_check.correct.registration import (
        apply_refinement,
        load_refinement,
        needs_refinement,
    )

    out = Path(out)
    reported, stale = None, False
    if judged.shared is not None:
        refined = load_refinement(out, judged.shared)
        stale = (refined is None and needs_refinement(judged.shared)
                 and (out / OUTPUTS.registration_refined).is_file())
        reported = apply_refinement(judged.shared, refined)
    return CorrectedRun.of(judged, reported_shared=reported,
                           corrections=load_corrections(out)), stale
