"""The first lines after a run that failed on a shared error (``report.headline``)."""

from __future__ import annotations

from pgt_check.report.headline import failure_headline

REG = {
    "status": "failed", "kind": "rigid", "effect_px": 8.3, "effect_px_ci": [7.7, 8.6],
    "angle_deg": 0.6, "angle_deg_ci": [0.54, 0.66], "translation": 0.008,
    "translation_ci": [0.006, 0.01], "n_frames": 13, "ambiguous_with_calibration": True,
}
CAL = {"status": "finding", "principal_point_shift_px": [-7.4, -1.7], "rotation_deg": 0.85}


def _summary(reg: dict, cal: dict, passed: bool = False) -> dict:
    return {
        "gate": {"passed": passed},
        "shared_errors": {"registration": reg, "similarity": {"status": "passed"},
                          "drift": {"status": "passed"}, "calibration": {"cam": cal}},
        "settings": {"input": {"trajectory": "t.txt", "mesh": "m.ply"}},
    }


def test_ambiguous_registration_reads_as_calibration_with_the_commands(tmp_path):
    (tmp_path / "calibrated_sensors.txt").write_text("x")
    lines = failure_headline(_summary(REG, CAL), tmp_path)
    assert lines[0].startswith("FAILED on an error all frames share: the whole trajectory")
    assert "8.3 px (95 % 7.7-8.6)" in lines[0] and "0.6 deg" in lines[0]
    assert "0.008 scene units" in lines[0]
    assert lines[1].startswith("most likely: the photo camera's calibration")
    assert any("--remove-calibration true" in x for x in lines)
    assert any("--sensors" in x and "calibrated_sensors.txt" in x for x in lines)
    # with the exact form written too, it is the fix; the sensors file the alternative
    (tmp_path / "calibrated").mkdir()
    (tmp_path / "calibrated" / "trajectories.txt").write_text("x")
    lines = failure_headline(_summary(REG, CAL), tmp_path)
    fix = [x for x in lines if x.startswith("fix")]
    assert len(fix) == 1 and "calibrated/trajectories.txt" in fix[0] and "rig" in fix[0]
    assert any(x.startswith("or, as intrinsics only") and "--sensors" in x for x in lines)
    assert "--shading shaded" not in fix[0]
    # mesh colours painted with these poses: the re-run judges on the geometry
    textured = {**_summary(REG, CAL), "shared_errors": {**_summary(REG, CAL)["shared_errors"],
                                                         "texture": {"status": "finding"}}}
    fix = [x for x in failure_headline(textured, tmp_path) if x.startswith("fix")]
    assert fix[0].endswith("--shading shaded")


def test_plain_misregistration_and_quiet_cases(tmp_path):
    lines = failure_headline(
        _summary({**REG, "ambiguous_with_calibration": False}, {"status": "passed"}), tmp_path
    )
    assert "misregistration" in lines[1] and "--registration-rounds" in lines[2]
    # a passed gate, or no failed shared check: nothing
    assert failure_headline(_summary(REG, CAL, passed=True), tmp_path) == []
    assert failure_headline(_summary({"status": "passed"}, CAL), tmp_path) == []
