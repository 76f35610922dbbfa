"""The correction stage's typed result: ``CorrectedRun`` keeps the verdicts, adds the corrected
poses as correction columns of their frames only, reports the refined registration estimate,
and ``stored_corrections`` rebuilds it from a run folder for ``pgt-check report``."""

from __future__ import annotations

from pgt_check.correct.correction import Correction, save_corrections
from pgt_check.correct.registration import refine_registration, save_refinement
from pgt_check.correct.result import CorrectedRun, stored_corrections
from tests.pgt_check.correct.test_registration import FakeMeasure, moved_case  # noqa: F401


def test_corrections_become_columns_of_their_frames_only(moved_case):  # noqa: F811
    *_, judged = moved_case
    fid = judged.frames[3].frame_id
    c = Correction(fid, True, "", drot_deg=0.4, dt=0.01, rounds=2, applied=True)
    run = CorrectedRun.of(judged, corrections={fid: c})
    rows = run.rows()
    assert rows[3]["corr_applied"] is True and rows[3]["corr_drot_deg"] == 0.4
    assert all("corr_applied" not in r for i, r in enumerate(rows) if i != 3)
    # the verdict columns are the verdict stage's
    strip = [{k: v for k, v in r.items() if not k.startswith("corr_")} for r in rows]
    assert strip == judged.rows()


def test_the_reported_checks_are_the_refined_ones_the_verdicts_keep_the_judged(moved_case):  # noqa: F811
    true, checked, _, config, ms, judged = moved_case
    refined = refine_registration(checked.frames, ms, judged.shared, config, FakeMeasure(true))
    from pgt_check.correct.registration import apply_refinement

    reported = apply_refinement(judged.shared, refined)
    run = CorrectedRun.of(judged, reported_shared=reported)
    assert run.shared is judged.shared and run.shared_as_reported is reported
    section = run.summary_extra()["shared_errors"]["registration"]
    assert section["refinement"]["rounds"]
    assert "refinement" not in judged.summary_extra()["shared_errors"]["registration"]
    assert set(CorrectedRun.of(judged).summary_extra()) == {"shared_errors"}


def test_stored_corrections_rebuild_the_result_from_a_run_folder(moved_case, tmp_path):  # noqa: F811
    true, checked, _, config, ms, judged = moved_case
    fid = judged.frames[0].frame_id
    save_corrections(tmp_path, [Correction(fid, False, "not_verified", rounds=3)])
    run, stale = stored_corrections(judged, tmp_path)
    assert not stale and run.rows()[0]["corr_reason"] == "not_verified"
    assert run.shared_as_reported.registration == judged.shared.registration  # nothing stored
    refined = refine_registration(checked.frames, ms, judged.shared, config, FakeMeasure(true))
    save_refinement(tmp_path, refined)
    run, stale = stored_corrections(judged, tmp_path)
    assert not stale and run.shared_as_reported.registration.refinement is not None
    # a refinement measured for another estimate is stale: left out, and said
    other = tmp_path / "other"
    other.mkdir()
    (other / "registration_refined.json").write_text(
        (tmp_path / "registration_refined.json").read_text().replace('"start"', '"x_start"'))
    run, stale = stored_corrections(judged, other)
    assert stale and run.shared_as_reported.registration.refinement is None
