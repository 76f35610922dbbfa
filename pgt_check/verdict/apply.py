"""Stage 2 over a run: run-level checks, then verdicts for stored measurements as flat rows."""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, replace
from typing import Any

from pgt_check.config import RunConfig
from pgt_check.enhance.base import Evidence
from pgt_check.measure.record import FrameMeasurement
from pgt_check.verdict.decide import (
    Judgement,
    Verdict,
    judge,
    own_outcomes,
    path_outcomes,
    vouched_reference,
)
from pgt_check.verdict.frame_bounds import (
    calibrations_to_remove,
    frame_accuracy_columns,
    world_sensitivity,
)
from pgt_check.verdict.off_mesh import off_mesh_frames
from pgt_check.verdict.shared import SharedChecks, run_shared_checks
from pgt_check.verdict.shared_results import Sensitivity
from pgt_check.verdict.status import NOT_CHECKED

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
class RunJudgement:
    """Rows (measurement columns + ``VERDICT_COLUMNS``) and the run-level checks."""

    rows: list[dict[str, Any]]
    shared: SharedChecks | None

    def summary_extra(self) -> dict[str, Any]:
        return {} if self.shared is None else {"shared_errors": self.shared.summary()}


def judge_run(measurements: Iterable[FrameMeasurement], config: RunConfig) -> RunJudgement:
    """Run-level checks on all measurements (trajectory order), then each frame's judgement;
    a frame below ``min_coverage`` whose neighbours see the mesh well FAILs ``off_mesh``
    (``pgt_check.verdict.off_mesh``).

    Measurements are not changed (records.jsonl stays as measured)."""
    ms = list(measurements)
    shared = run_shared_checks(ms, config) if config.verdict.shared_checks and ms else None
    if shared is not None and shared.registration.status != NOT_CHECKED:
        # what a world rotation / translation does to the images (the shared detection limit)
        sens = Sensitivity(*world_sensitivity(ms))
        shared = replace(shared, registration=replace(shared.registration, sensitivity=sens))
    v = config.verdict
    outs = [path_outcomes(m, v, shared) for m in ms]
    own = own_outcomes(ms, v, shared, outs)
    judged = [judge(m, v, shared, own, out) for m, out in zip(ms, outs, strict=True)]
    # a render that shows (almost) nothing of a mesh its neighbours see well: a gross pose
    # error, not missing evidence (``verdict.off_mesh``)
    off = off_mesh_frames(ms, v.min_coverage)
    judged = [
        Judgement(Verdict.FAIL, off[m.frame_id], Evidence.ABSOLUTE.value, "", "")
        if m.frame_id in off else j
        for m, j in zip(ms, judged, strict=True)
    ]
    # second pass: a frame judged through a reference the run does not pass is judged
    # through another tried reference that it passes, where one aligned (``vouched_reference``)
    first = {m.frame_id: j.verdict for m, j in zip(ms, judged, strict=True)}
    # the pose accuracy each frame's absolute evidence supports (``verdict.frame_bounds``), after
    # taking out the calibration error the verdicts take out
    cals = calibrations_to_remove(
        v, None if shared is None else shared.summary(), [m.camera_id for m in ms]
    )
    accuracy = frame_accuracy_columns(ms, cals)
    rows = []
    for m, j in zip(ms, judged, strict=True):
        m2 = vouched_reference(m, j, first, v)
        if m2 is not None:
            m, j = m2, judge(m2, v, shared, own, path_outcomes(m2, v, shared))
        row = m.row()
        row.update(
            verdict=j.verdict.value,
            reason=j.reason,
            threshold_px=v.threshold_for(m.width, m.height),
            evidence=j.evidence,
            raw_verdict=j.raw_verdict,
            enhanced_verdict=j.enhanced_verdict,
            disagree=j.disagree,
            drift_px=None if shared is None else shared.drift_px.get(m.frame_id),
            decided_by=j.decided_by,
        )
        row.update(accuracy[m.frame_id])
        row["camera_id"] = m.camera_id  # not a frames.csv column (calibrated_sensors.txt)
        rows.append(row)
    return RunJudgement(rows, shared)


def apply_verdicts(
    measurements: Iterable[FrameMeasurement], config: RunConfig
) -> list[dict[str, Any]]:
    """The rows of ``judge_run``."""
    return judge_run(measurements, config).rows
