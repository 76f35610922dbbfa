"""The verdict stage's typed result: ``judge_run`` returns one ``FrameResult`` per frame and the
typed run-level checks; ``row()`` gives exactly the frames.csv columns the report writes."""

from __future__ import annotations

import math

import pytest

from pgt_check.config import RunConfig
from pgt_check.report.outputs import FRAME_COLUMNS
from pgt_check.verdict import FrameResult, RunResult, judge_run
from pgt_check.verdict.frame_bounds import ACCURACY_COLUMNS, FrameBound
from pgt_check.verdict.result import VERDICT_COLUMNS
from pgt_eval import shared_transform
from tests.pgt_check.verdict.test_shared import _trajectory, measurements


@pytest.fixture(scope="module")
def judged() -> RunResult:
    true = _trajectory(12)
    return judge_run(measurements(true, true), RunConfig())


def test_judge_run_returns_one_typed_result_per_frame_in_order(judged):
    assert isinstance(judged, RunResult) and judged.shared is not None
    assert all(isinstance(f, FrameResult) for f in judged.frames)
    assert [f.frame_id for f in judged.frames] == [f.frame_id for f in _trajectory(12).frames]
    f = judged.frames[0]
    assert f.verdict == "PASS" and f.reason == "" and f.judgement.evidence == "absolute"
    assert f.threshold_px == pytest.approx(0.02 * math.hypot(640, 480))
    assert f.bound.bounded and f.bound.evidence == "raw"  # absolute evidence: a pose bound


def test_row_holds_the_verdict_accuracy_and_measurement_columns(judged):
    rows = judged.rows()
    assert len(rows) == 12
    for f, row in zip(judged.frames, rows, strict=True):
        assert set(VERDICT_COLUMNS) | set(ACCURACY_COLUMNS) <= set(row)
        assert row["frame_id"] == f.frame_id and row["verdict"] == f.verdict
        assert row["threshold_px"] == f.threshold_px and row["camera_id"] == "cam0"
        assert row["acc_rot_bound_deg"] == f.bound.accuracy.rotation_bound_deg
        # every frames.csv column but the correction tail comes from the row
        missing = [c for c in FRAME_COLUMNS if c not in row and not c.startswith("corr_")]
        assert not missing, missing


def test_a_frame_without_absolute_evidence_has_no_bound_and_says_why():
    b = FrameBound()
    cols = b.columns()
    assert not b.bounded and cols["acc_rot_bound_deg"] is None
    assert cols["acc_reason"] == "no_absolute_evidence" and cols["acc_evidence"] == ""


def test_a_moved_trajectory_fails_through_the_typed_checks():
    true = _trajectory(30)
    moved = judge_run(measurements(true, _moved(true)), RunConfig())
    assert moved.shared.registration.status == "failed"
    assert {f.verdict for f in moved.frames} == {"FAIL"}
    assert moved.summary_extra()["shared_errors"]["registration"]["status"] == "failed"


def _moved(traj):
    from pgt_eval import move_trajectory

    return move_trajectory(traj, shared_transform(traj, 1.0, 0.05, seed=4))
