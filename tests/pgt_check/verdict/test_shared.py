"""Run-level checks and the per-frame judgement with evidence kinds (issue #13), on synthetic
measurements: the absolute evidence of each frame is simulated exactly as the measurement
makes it (a mesh point seen by the render at the CHECKED pose, observed by the photo at the
TRUE pose), so the tests need no rendering."""

from __future__ import annotations

import numpy as np
import pytest

from pgt_check.config import RunConfig
from pgt_check.enhance.base import Evidence
from pgt_check.measure import AbsoluteEvidence, FrameMeasurement, PathMeasurement
from pgt_check.types import Camera, Frame, Trajectory
from pgt_check.verdict import judge_run
from pgt_eval import shared_transform

CAM = Camera.pinhole(640, 480, 500.0, 500.0, 319.5, 239.5)


def _look_at(eye, target):
    z = np.asarray(target, float) - eye
    z /= np.linalg.norm(z)
    x = np.cross(z, [0, 0, 1.0])
    x /= np.linalg.norm(x)
    m = np.eye(4)
    m[:3, :3] = np.stack([x, np.cross(z, x), z], axis=1)
    m[:3, 3] = eye
    return m


def _trajectory(n: int = 30) -> Trajectory:
    frames = []
    for i in range(n):
        a = 2 * np.pi * i / n
        eye = np.array([3.0 * np.cos(a), 3.0 * np.sin(a), 1.5])
        frames.append(Frame(f"f{i:03d}", CAM, _look_at(eye, [0, 0, 0.8]), timestamp=float(i)))
    return Trajectory(tuple(frames), "synthetic", "lamar")


def _path(kind: str, err: float, inliers: int = 120) -> PathMeasurement:
    return PathMeasurement(
        kind=kind, method="render" if kind == "raw" else "reproject",
        evidence=Evidence.ABSOLUTE if kind == "raw" else Evidence.RELATIVE,
        n_kpts_render=500, n_kpts_photo=500, n_matches=200, n_inliers=inliers,
        inlier_ratio=inliers / 200, reason="", photo_from_render=tuple(map(tuple, np.eye(3))),
        corner_error_px=err,
    )


def measurements(true: Trajectory, checked: Trajectory, *, relative: bool = False,
                 seed: int = 0, n_points: int = 60) -> list[FrameMeasurement]:
    """One measurement per frame of ``checked``; the photos were taken at ``true``'s poses.

    relative=False: the raw path decides (absolute); True: the raw path has too few inliers
    to be verifiable and a reprojected reference decides with a small error, as on
    meshes whose own appearance does not match the photos."""
    rng = np.random.default_rng(seed)
    world_pts = rng.uniform([-1.5, -1.5, 0.0], [1.5, 1.5, 1.6], size=(400, 3))
    out = []
    for t, c in zip(true.frames, checked.frames, strict=True):
        x_true = world_pts @ t.cam_from_world[:3, :3].T + t.cam_from_world[:3, 3]
        x_chk = world_pts @ c.cam_from_world[:3, :3].T + c.cam_from_world[:3, 3]
        uv = x_true[:, :2] / x_true[:, 2:3] * 500.0 + [319.5, 239.5]
        ok = (x_true[:, 2] > 0.1) & (uv >= 0).all(1) & (uv < [640, 480]).all(1)
        idx = np.flatnonzero(ok)[:n_points]
        uv = uv[idx] + rng.normal(0, 0.7, (len(idx), 2))
        err = float(np.median(np.linalg.norm(
            x_chk[idx, :2] / x_chk[idx, 2:3] * 500.0 + [319.5, 239.5] - uv, axis=1)))
        if relative:
            raw, enh, chosen = _path("raw", 10.0, inliers=8), _path("enhanced", 1.0), "enhanced"
        else:
            raw, enh, chosen = _path("raw", err), None, "raw"
        out.append(FrameMeasurement(
            frame_id=c.frame_id, timestamp=c.timestamp, image_path=None, width=640, height=480,
            center=tuple(c.center), coverage=0.9, raw=raw, enhanced=enh, verdict_path=chosen,
            world_from_cam=tuple(map(tuple, c.world_from_cam)),
            intrinsics=(500.0, 500.0, 319.5, 239.5), camera_id="cam0",
            evidence=AbsoluteEvidence(("raw",), tuple(map(tuple, uv)), tuple(map(tuple, x_chk[idx]))),
        ))
    return out


def _move(traj: Trajectory, deg: float, shift: float, scale: float = 1.0) -> Trajectory:
    from pgt_eval import move_trajectory

    return move_trajectory(traj, shared_transform(traj, deg, shift, scale=scale, seed=4))


def _with_pp_shift(ms: list[FrameMeasurement], dx: float) -> list[FrameMeasurement]:
    """The measurements with every photo point moved by ``dx`` px in x: a principal point off
    by ``dx`` in the photo camera (every frame shifted the same way)."""
    return [m.__class__(**{**m.__dict__, "evidence": AbsoluteEvidence(
        ("raw",), tuple((u + dx, v) for u, v in m.evidence.pts2d), m.evidence.pts_cam)})
        for m in ms]


@pytest.fixture(scope="module")
def truth() -> Trajectory:
    return _trajectory()


def test_correct_trajectory_passes_every_check(truth):
    j = judge_run(measurements(truth, truth), RunConfig())
    se = j.shared.summary()
    assert se["registration"]["status"] == "passed", se["registration"]["message"]
    assert se["drift"]["status"] == "passed"
    assert all(r["verdict"] == "PASS" and r["evidence"] == "absolute" for r in j.rows())


@pytest.mark.parametrize("relative", [False, True])
def test_misregistered_trajectory_fails_every_frame(truth, relative):
    """2 deg + 4 % of the depth (3 m): every frame FAIL, whichever path decided, and the
    estimate recovers the injected rotation within 30 %."""
    moved = _move(truth, 2.0, 0.12)
    j = judge_run(measurements(truth, moved, relative=relative), RunConfig())
    reg = j.shared.summary()["registration"]
    assert reg["status"] == "failed"
    assert reg["angle_deg"] == pytest.approx(2.0, rel=0.3)
    assert all(r["verdict"] == "FAIL" for r in j.rows())
    # frames whose own error is below the per-frame threshold fail by the run-level check
    assert any(r["reason"].startswith("registration") for r in j.rows())


def test_relative_pass_needs_a_passed_registration_check(truth):
    ms = measurements(truth, truth, relative=True)
    j = judge_run(ms, RunConfig())
    assert all(r["verdict"] == "PASS" and r["evidence"] == "relative+registration" for r in j.rows())
    j = judge_run(ms, RunConfig.from_dict({"run_checks": {"enabled": False}}))
    assert all(r["verdict"] == "UNVERIFIABLE" for r in j.rows())
    assert all(r["reason"].startswith("relative_evidence_only") for r in j.rows())


def test_relative_frames_without_absolute_evidence_are_not_verified(truth):
    ms = [m.__class__(**{**m.__dict__, "evidence": None})
          for m in measurements(truth, truth, relative=True)]
    j = judge_run(ms, RunConfig())
    assert j.shared.summary()["registration"]["status"] == "not_checked"
    assert {r["verdict"] for r in j.rows()} == {"UNVERIFIABLE"}


def test_similarity_is_estimated(truth):
    moved = _move(truth, 0.0, 0.0, scale=1.04)
    j = judge_run(measurements(truth, moved), RunConfig())
    sim = j.shared.summary()["similarity"]
    assert sim["status"] == "failed"
    # the estimate is the correction: it undoes the injected scale
    assert sim["scale"] == pytest.approx(1 / 1.04, abs=0.3 * 0.04)


def test_drifting_segment_is_separated(truth):
    from pgt_eval import drift_trajectory, roc_auc

    drifted, ids = drift_trajectory(truth, 0.6, 2.0, 0.12, seed=5)
    j = judge_run(measurements(truth, drifted), RunConfig())
    labels = np.array([r["frame_id"] in set(ids) for r in j.rows()])
    score = np.array([r["drift_px"] or 0.0 for r in j.rows()])
    assert roc_auc(score, labels) >= 0.95
    assert not any(r["verdict"] != "PASS" for r, lab in zip(j.rows(), labels, strict=True)
                   if not lab and r["frame_id"] < "f010")


def test_drift_covers_frames_without_evidence_of_their_own(truth):
    """Drifting frames whose own absolute evidence is missing (their raw render found too few
    inliers; a reprojected neighbour, which shares the drift, passes them) lie in the flagged
    segment: they are scored along the trajectory and FAIL, not PASS on relative evidence."""
    from pgt_eval import drift_trajectory

    drifted, ids = drift_trajectory(truth, 0.6, 2.0, 0.12, seed=5)
    absolute = measurements(truth, drifted)
    relative = measurements(truth, drifted, relative=True)
    blind = {absolute[k].frame_id for k in (22, 23, 25)}
    assert blind <= set(ids)
    ms = [
        r.__class__(**{**r.__dict__, "evidence": None}) if a.frame_id in blind else a
        for a, r in zip(absolute, relative, strict=True)
    ]
    j = judge_run(ms, RunConfig())
    rows = {r["frame_id"]: r for r in j.rows()}
    drift = j.shared.summary()["drift"]
    assert drift["status"] == "failed"
    for fid in blind:
        assert rows[fid]["verdict"] != "PASS", rows[fid]
        assert rows[fid]["drift_px"] > j.shared.threshold_px
    # inside the segment (or next to it, its interpolated bound above the threshold): FAIL
    first, last = drift["segments"][0]
    inside = {r["frame_id"] for r in j.rows() if first <= r["frame_id"] <= last}
    assert blind & inside
    for fid in blind & inside:
        assert rows[fid]["verdict"] == "FAIL" and rows[fid]["reason"].startswith("drift")
    covered = {e["frame_id"]: e["own_evidence"] for e in drift["per_frame"]}
    assert all(covered[fid] is False for fid in blind)
    assert sum(covered.values()) == len(ms) - len(blind)
    # segments name the frames (first, last) of the trajectory
    assert all(a in rows and b in rows for a, b in drift["segments"])


def test_a_relative_pass_needs_the_drift_there_within_the_threshold(truth):
    """Registration passed, drift check not failed, but the drift score at this frame is above
    the threshold (only not significantly): its relative PASS is not vouched for."""
    from dataclasses import replace

    from pgt_check.verdict.decide import judge

    ms = measurements(truth, truth, relative=True)
    j = judge_run(ms, RunConfig())
    shared = j.shared
    assert shared.registration_status == "passed"
    m = ms[5]
    assert judge(m, RunConfig().verdict, shared).evidence == "relative+registration"
    above = replace(shared, drift_px={**shared.drift_px, m.frame_id: 3 * shared.threshold_px})
    out = judge(m, RunConfig().verdict, above)
    assert out.verdict.value == "UNVERIFIABLE"
    assert out.reason.startswith("relative_evidence_only") and "drifts by" in out.reason


def test_calibration_is_a_finding_and_can_be_removed(truth):
    """Photos taken with a principal point 5 px off (every frame shifted the same way)."""
    from pgt_eval import change_intrinsics

    shifted = change_intrinsics(truth, principal_shift=(5.0, 0.0))
    ms = measurements(truth, truth)
    # the photo points move by +5 px in x (the photo camera's principal point)
    ms = _with_pp_shift(ms, 5.0)
    assert shifted.frames[0].camera.principal_point[0] == pytest.approx(324.5)
    j = judge_run(ms, RunConfig())
    cal = next(iter(j.shared.summary()["calibration"].values()))
    assert cal["status"] in ("finding", "failed")
    assert cal["principal_point_shift_px"][0] == pytest.approx(5.0, rel=0.3)
    j2 = judge_run(ms, RunConfig.from_dict({"run_checks": {"remove_calibration": True}}))
    assert j2.shared.summary()["registration"]["status"] == "passed"


def test_calibration_translation_is_reported_and_removed(truth):
    """Photos from a camera 4 cm beside the posed sensor: with ``calibration_translation`` the
    summary states the camera-to-rig translation, and --remove-calibration removes it."""
    t = np.array([0.04, 0.0, 0.0])
    ms = []
    for m in measurements(truth, truth):
        xc = np.asarray(m.evidence.pts_cam) + t
        uv = xc[:, :2] / xc[:, 2:3] * 500.0 + [319.5, 239.5]
        ms.append(m.__class__(**{**m.__dict__, "evidence": AbsoluteEvidence(
            ("raw",), tuple(map(tuple, uv)), m.evidence.pts_cam)}))
    cfg = {"run_checks": {"calibration_translation": True, "remove_calibration": True}}
    j = judge_run(ms, RunConfig.from_dict(cfg))
    cal = next(iter(j.shared.summary()["calibration"].values()))
    assert cal["translation"] is not None
    np.testing.assert_allclose(cal["translation"], t, atol=0.3 * 0.04)
    lo, hi = np.asarray(cal["translation_ci"]).T  # (3, 2) per-component intervals
    assert np.all(lo <= hi) and lo[0] < 0.04 * 1.3 and hi[0] > 0.04 * 0.7
    assert "camera-to-rig translation" in cal["message"]
    assert j.shared.summary()["registration"]["status"] == "passed"
    assert j.shared.summary()["drift"]["status"] == "passed"
    # without the option no translation is estimated
    plain = judge_run(ms, RunConfig())
    assert next(iter(plain.shared.summary()["calibration"].values()))["translation"] is None


def test_calibration_from_a_trusted_run_keeps_misregistration_visible(truth, tmp_path):
    """A calibration estimated on the same run may absorb a misregistration where views
    cannot separate them; one from a trusted run (same camera) cannot."""
    import json

    shift = 5.0

    trusted = judge_run(_with_pp_shift(measurements(truth, truth), shift), RunConfig())
    path = tmp_path / "summary.json"
    path.write_text(json.dumps({"shared_errors": trusted.shared.summary()}))
    moved = _move(truth, 2.0, 0.0)
    ms = _with_pp_shift(measurements(truth, moved), shift)
    cfg = RunConfig.from_dict({"run_checks": {"calibration_from": str(path)}})
    reg = judge_run(ms, cfg).shared.summary()["registration"]
    assert reg["status"] == "failed"
    assert reg["angle_deg"] == pytest.approx(2.0, rel=0.3)
    # the given trajectory with the trusted calibration passes
    ok = judge_run(_with_pp_shift(measurements(truth, truth), shift), cfg)
    assert ok.shared.summary()["registration"]["status"] == "passed"
    assert all(r["verdict"] == "PASS" for r in ok.rows())


def test_calibration_from_a_trusted_run_sees_the_camera_change(truth, tmp_path):
    """Calibrated once on a trusted run (principal point 5 px off); a later run of the same
    trajectory whose camera moved its principal point by another 6 px: the calibration
    change FAILs and so do the frames, where the same run with the trusted camera passes."""
    import json

    trusted = judge_run(_with_pp_shift(measurements(truth, truth), 5.0), RunConfig())
    path = tmp_path / "summary.json"
    path.write_text(json.dumps({"shared_errors": trusted.shared.summary()}))
    cfg = RunConfig.from_dict({"run_checks": {"calibration_from": str(path)}})
    same = judge_run(_with_pp_shift(measurements(truth, truth, seed=1), 5.0), cfg)
    change = next(iter(same.shared.summary()["calibration_change"].values()))
    assert change["status"] == "passed", change["message"]
    assert all(r["verdict"] == "PASS" for r in same.rows())
    changed = judge_run(_with_pp_shift(measurements(truth, truth, seed=1), 11.0), cfg)
    change = next(iter(changed.shared.summary()["calibration_change"].values()))
    assert change["status"] == "failed", change["message"]
    assert change["principal_point_shift_px"][0] == pytest.approx(6.0, rel=0.3)
    assert "CHANGED since the trusted run" in change["message"]
    assert all(r["verdict"] == "FAIL" for r in changed.rows())
    # these views also see the shift left as drift or misregistration: those checks come
    # first; the camera change fails the frames where they pass (below)
    assert all(r["reason"].startswith(("calibration: this camera changed", "registration:",
                                       "drift:")) for r in changed.rows())


def test_a_camera_change_names_a_trusted_run_that_could_not_separate(truth, tmp_path):
    """A calibration change against a trusted run whose calibration was not separable from its
    own registration (7-Scenes: a trusted run on the last third of a sweep took in that
    segment's offset, reports/trusted_subsets.md): the FAIL also names that explanation and
    what to do; against a separable trusted run it does not."""
    import json

    trusted = judge_run(_with_pp_shift(measurements(truth, truth), 5.0), RunConfig()).shared
    changed = _with_pp_shift(measurements(truth, truth, seed=1), 11.0)
    messages = {}
    for separable in (True, False):
        se = trusted.summary()
        for entry in se["calibration"].values():
            entry["separable_from_registration"] = separable
        path = tmp_path / f"summary-{separable}.json"
        path.write_text(json.dumps({"shared_errors": se}))
        cfg = RunConfig.from_dict({"run_checks": {"calibration_from": str(path)}})
        (change,) = judge_run(changed, cfg).shared.summary()["calibration_change"].values()
        assert change["status"] == "failed", change["message"]
        messages[separable] = change["message"]
    assert "took in part of the trusted run's own misregistration" in messages[False]
    assert "misregistration" not in messages[True]
    assert messages[False].startswith(messages[True])


def test_a_change_a_non_separable_trusted_run_may_carry_is_inconclusive(truth, tmp_path):
    """A trusted calibration whose run could not tell it from its own registration may carry
    up to that run's shared threshold of misregistration (a registration is known to no better
    when it passes or is asserted), which views the trusted run did not see need not share;
    errors add. Judged on views the trusted run (an arc of the circle) does not cover, a change
    between the threshold and the threshold plus that is INCONCLUSIVE and fails no frame
    (7-Scenes: a trusted run on the last third of a sweep, 4.2 px against 2.4,
    reports/trusted_subsets.md). Against a separable trusted run, on the views the trusted
    run saw (a moved copy of it), or above both, the same kind of change FAILs."""
    import json

    arc, other = (Trajectory(f, "synthetic", "lamar") for f in (truth.frames[:12],
                                                                truth.frames[15:]))
    trusted = judge_run(_with_pp_shift(measurements(arc, arc), 5.0), RunConfig()).shared
    thr = trusted.threshold_px
    for judged, shift, separable, expected in ((other, 1.6 * thr, True, "failed"),
                                               (other, 1.6 * thr, False, "inconclusive"),
                                               (arc, 1.6 * thr, False, "failed"),
                                               (other, 3.5 * thr, False, "failed")):
        se = trusted.summary()
        assert se["threshold_px"] == pytest.approx(thr)
        for entry in se["calibration"].values():
            assert len(entry["views"]) == len(arc.frames)
            entry["separable_from_registration"] = separable
        path = tmp_path / f"summary-{separable}-{shift:.0f}-{len(judged.frames)}.json"
        path.write_text(json.dumps({"shared_errors": se}))
        cfg = RunConfig.from_dict({"run_checks": {"calibration_from": str(path)}})
        run = judge_run(_with_pp_shift(measurements(judged, judged, seed=1), 5.0 + shift), cfg)
        (change,) = run.shared.summary()["calibration_change"].values()
        case = (len(judged.frames), shift, separable, change["message"])
        assert change["status"] == expected, case
        assert change["effect_px"] > thr, case
        # the summary says how much it allowed (absent where it allowed nothing)
        allowance = change.get("allowance_px")
        if separable or judged is arc:
            assert allowance is None and "allowance_px" not in run.shared.summary()[
                "registration"], case
        else:
            assert 0 < allowance <= thr, case
            assert run.shared.summary()["registration"]["allowance_px"] == pytest.approx(
                allowance)
            assert (change["effect_px_ci"][0] > thr + allowance) == (expected == "failed"), case
        if expected == "inconclusive":
            assert "may carry of its own run's misregistration" in change["message"]
            reg = run.shared.summary()["registration"]
            assert reg["status"] != "failed", reg["message"]
            assert not any(r["reason"].startswith(("calibration: this camera changed",
                                                   "registration:")) for r in run.rows())
        else:
            assert any(r["reason"].startswith(("calibration: this camera changed",
                                               "registration:")) for r in run.rows())


def test_an_asserted_registration_that_fails_names_the_calibration_translation(truth):
    """--remove-calibration asserts the registration; the photos' camera sits 10 cm beside the
    posed one (a camera-frame translation, which a rotation-and-zoom calibration cannot
    express): on an arc the registration check fails on what is left, and its message names
    --calibration-translation, with which the same run's registration passes."""
    from pgt_check.verdict.checks.registration import TRANSLATION_HINT

    arc = Trajectory(truth.frames[:10], "synthetic", "lamar")
    beside = np.eye(4)
    beside[:3, 3] = [0.1, 0.0, 0.0]
    posed = Trajectory(tuple(Frame(f.frame_id, f.camera, f.world_from_cam @ beside,
                                   timestamp=f.timestamp) for f in arc.frames),
                       "synthetic", "lamar")
    regs = {}
    for ct in (False, True):
        cfg = RunConfig.from_dict({"run_checks": {"remove_calibration": True,
                                                  "calibration_translation": ct}})
        regs[ct] = judge_run(measurements(arc, posed), cfg).shared.summary()["registration"]
    assert regs[False]["status"] == "failed", regs[False]["message"]
    assert regs[False]["message"].endswith(TRANSLATION_HINT)
    assert regs[True]["status"] == "passed", regs[True]["message"]
    # not asserted: a failed registration is a misregistration, no hint
    moved = judge_run(measurements(truth, _move(truth, 3.0, 0.0)), RunConfig())
    reg = moved.shared.summary()["registration"]
    assert reg["status"] == "failed" and "calibration-translation" not in reg["message"]


def test_a_changed_camera_fails_frames_the_other_checks_pass():
    from pgt_check.verdict.decide import _run_level
    from pgt_check.verdict.shared import SharedChecks
    from pgt_check.verdict.shared_results import (
        CalibrationCheck,
        CameraChecks,
        DriftCheck,
        RegistrationCheck,
    )

    reg = RegistrationCheck(status="passed", effect_px=0.5)
    drift = DriftCheck("passed", "", "drift passed")
    shared = SharedChecks(2.4, {"registration": reg, "similarity": reg, "drift": drift,
                                "calibration": CameraChecks()}, drift_threshold_px=4.8)
    assert _run_level("f1", shared, "absolute", True, "cam0")[0].value == "PASS"
    changed = shared.with_entries(calibration_change=CameraChecks(
        {"cam0": CalibrationCheck("failed", "", effect_px=6.1)}))
    v, reason, _ = _run_level("f1", changed, "absolute", True, "cam0")
    assert (v.value, reason) == ("FAIL", "calibration: this camera changed since the trusted "
                                         "run (6.1 px)")
    assert _run_level("f1", changed, "absolute", True, "cam1")[0].value == "PASS"  # other camera


def test_a_failed_registration_most_frames_disagree_with_is_inconclusive():
    """When the frames' own errors dominate the pooled fit (leaving frames out could not
    separate them; measured: castle, 4 of 10 frames perturbed, the 320 px presets), fewer
    than half of the frames agree with the fitted correction: one shared correction does not
    describe them, and the check says so instead of failing every frame."""
    from dataclasses import replace

    from pgt_check.verdict.shared_entries import shared_or_not as _shared_or_not
    from pgt_check.verdict.shared_results import RegistrationCheck

    entry = RegistrationCheck(status="failed", effect_px=48.0,
                              message="rigid registration FAILED: the trajectory is misregistered")
    disagree = _shared_or_not(entry, np.array([1.0, 2.0, 30.0, 40.0, 50.0, np.inf]), 8.0)
    assert disagree.status == "inconclusive"
    assert disagree.frames_agreeing == pytest.approx(2 / 5)
    assert disagree.message.startswith("rigid registration inconclusive: only 40%")
    agree = _shared_or_not(entry, np.array([1.0, 2.0, 3.0, 40.0]), 8.0)
    assert agree.status == "failed" and agree.frames_agreeing == pytest.approx(0.75)
    passed = _shared_or_not(replace(entry, status="passed"), np.array([30.0, 40.0]), 8.0)
    assert passed.status == "passed"


def test_each_frame_weighs_the_same_in_the_pooled_fits(truth):
    """A drifting segment (the last 12 of 30 frames, 3 deg) whose frames carry about twice
    the points of the others (several evidence sources): capped per frame, the correct
    majority keeps the registration and the segment is found as drift."""
    from pgt_check.verdict.shared import MAX_FRAME_EVIDENCE_POINTS, frame_evidence

    moved = _move(truth, 3.0, 0.0)
    checked = Trajectory(truth.frames[:18] + moved.frames[18:], "synthetic", "lamar")
    few = measurements(truth, checked, n_points=MAX_FRAME_EVIDENCE_POINTS)
    many = measurements(truth, checked, n_points=400)
    ms = few[:18] + many[18:]
    ev = frame_evidence(ms)
    assert max(len(m.evidence) for m in ms) > 1.5 * MAX_FRAME_EVIDENCE_POINTS
    assert all(len(e.pts2d) == MAX_FRAME_EVIDENCE_POINTS for e in ev)
    j = judge_run(ms, RunConfig())
    se = j.shared.summary()
    assert se["registration"]["status"] == "passed", se["registration"]["message"]
    assert se["drift"]["status"] == "failed"
    assert all(r["verdict"] == "PASS" for r in j.rows()[:18])
    # the windows find the segment from its third frame on (3 deg about the trajectory
    # centroid moves these images by only ~4 px per frame)
    assert sum(r["verdict"] == "FAIL" for r in j.rows()[18:]) >= 9


def test_long_runs_pool_a_bounded_number_of_points(truth, monkeypatch):
    """Past MAX_POOLED_POINTS / MAX_FRAME_EVIDENCE_POINTS frames each frame gives fewer points,
    evenly, never fewer than the floor; a shared 2-deg misregistration is still found."""
    import pgt_check.verdict.shared as shared

    monkeypatch.setattr(shared, "MAX_POOLED_POINTS", 20 * 60)  # 30 frames of 60 points
    moved = _move(truth, 2.0, 0.0)
    ms = measurements(truth, moved, n_points=60)
    ev = shared.frame_evidence(ms)
    assert {len(e.pts2d) for e in ev} == {40}
    assert sum(len(e.pts2d) for e in ev) <= shared.MAX_POOLED_POINTS
    monkeypatch.setattr(shared, "MAX_POOLED_POINTS", 10)
    assert {len(e.pts2d) for e in shared.frame_evidence(ms)} == {shared.MIN_FRAME_EVIDENCE_POINTS}
    monkeypatch.setattr(shared, "MAX_POOLED_POINTS", 20 * 60)
    se = judge_run(ms, RunConfig()).shared.summary()
    assert se["registration"]["status"] == "failed", se["registration"]["message"]


def _sweep(n: int, cam_rotation: np.ndarray | None = None) -> Trajectory:
    """A 7-Scenes-like sweep: the camera walks 60 deg around the scene looking at its middle;
    with ``cam_rotation`` the photos were taken by a camera turned by it against the given
    poses (a calibration error every frame shares)."""
    frames = []
    for i in range(n):
        a = np.radians(-30.0 + 60.0 * i / (n - 1))
        eye = np.array([3.0 * np.sin(a), -3.0 * np.cos(a), 1.2 + 0.2 * np.sin(i)])
        pose = _look_at(eye, [0.0, 0.0, 0.8])
        if cam_rotation is not None:
            pose[:3, :3] = pose[:3, :3] @ cam_rotation
        frames.append(Frame(f"f{i:03d}", CAM, pose, timestamp=float(i)))
    return Trajectory(tuple(frames), "synthetic", "lamar")


@pytest.mark.parametrize("subset", ["spread", "first", "last"])
def test_trusted_calibration_workflow_on_any_subset_of_a_sweep(subset, tmp_path):
    """Issue 38 item 2: ``--remove-calibration`` on 20 frames of a sweep (spread along it, or
    its first or last third; a quarter of them with errors of their own) keeps the
    calibration estimate whatever the separability test says (the ambiguity reported), the
    registration passes, and 30 other clean frames checked ``--calibration-from`` that run
    PASS with the calibration unchanged."""
    import json

    from pgt_check.geometry.transforms import axis_angle_to_rotmat
    from pgt_eval import perturb_trajectory

    rot = axis_angle_to_rotmat(np.array([1.0, 0.6, 0.2]), 0.9).T
    given, true = _sweep(90), _sweep(90, rot)
    idx = {"spread": range(0, 90, 9), "first": range(0, 30, 3), "last": range(60, 90, 3)}[subset]
    idx = sorted(set(idx) | {i + 1 for i in idx})[:20]
    pick = lambda t, ii: Trajectory(tuple(t.frames[i] for i in ii), "s", "lamar")  # noqa: E731
    wrong, _ = perturb_trajectory(pick(given, idx), 0.25, (0.5, 4.0), (0.03, 0.24), seed=1)
    trusted = judge_run(measurements(pick(true, idx), wrong),
                        RunConfig.from_dict({"run_checks": {"remove_calibration": True}}))
    se = trusted.shared.summary()
    (cal,) = se["calibration"].values()
    assert cal["rotation"] is not None and cal["rotation_deg"] == pytest.approx(0.9, abs=0.15)
    if not cal["separable_from_registration"]:
        assert "taken as calibration" in cal["message"]
    assert se["registration"]["status"] == "passed", se["registration"]["message"]
    path = tmp_path / "summary.json"
    path.write_text(json.dumps({"shared_errors": se}))
    other = [i for i in range(0, 90, 3) if i not in idx][:30]
    j = judge_run(measurements(pick(true, other), pick(given, other)),
                  RunConfig.from_dict({"run_checks": {"calibration_from": str(path)}}))
    se2 = j.shared.summary()
    assert se2["registration"]["status"] == "passed", se2["registration"]["message"]
    assert all(e["status"] == "passed" for e in se2["calibration_change"].values())
    assert np.mean([r["verdict"] == "PASS" for r in j.rows()]) >= 0.9


def test_a_barred_path_gives_no_points_to_the_pooled_checks() -> None:
    """``frame_evidence(exclude_paths=...)``: the points of a path this run barred
    (``verdict.separation``) are left out of the registration / calibration / drift fits; a
    frame with no other path's points is left out entirely."""
    import numpy as np

    from pgt_check.measure.record import AbsoluteEvidence, FrameMeasurement
    from pgt_check.verdict.shared import frame_evidence

    rng = np.random.default_rng(0)
    p2 = rng.uniform(0, 100, (30, 2))
    pc = np.c_[rng.uniform(-1, 1, (30, 2)), rng.uniform(2, 4, 30)]
    both = AbsoluteEvidence(("raw", "mariner"), tuple(map(tuple, p2)), tuple(map(tuple, pc)),
                            (10, 20))
    enh_only = AbsoluteEvidence(("mariner",), tuple(map(tuple, p2[:20])),
                                tuple(map(tuple, pc[:20])), (20,))
    ms = [FrameMeasurement(frame_id=f, timestamp=None, image_path=None, width=100, height=100,
                           center=(0.0, 0.0, 0.0), camera_id="c",
                           intrinsics=(100.0, 100.0, 50.0, 50.0),
                           world_from_cam=tuple(map(tuple, np.eye(4))), evidence=e)
          for f, e in (("a", both), ("b", enh_only))]
    full = frame_evidence(ms)
    assert [len(e.pts2d) for e in full] == [30, 20]
    kept = frame_evidence(ms, exclude_paths=("enhanced",))
    assert [e.frame_id for e in kept] == ["a"]
    np.testing.assert_allclose(kept[0].pts2d, p2[:10])


def test_registration_is_fitted_outside_a_drifting_segment(truth):
    """The last 40 % of the frames drift to 3 deg, and every given pose scatters by 0.5 deg
    (as real given poses do: the frame screening's null is wide, so it leaves out only the
    end of the segment). Pooled with the rest of the segment, the registration failed at ~3
    px and every frame outside the segment FAILed (bm_mictlantecuhli, reports/scenes_loso.md);
    fitted on the frames outside the flagged segment it does not fail, and they PASS."""
    from dataclasses import replace

    from pgt_eval import drift_trajectory, perturb_pose

    drifted, ids = drift_trajectory(truth, 0.6, 3.0, 0.15, seed=5)
    rng = np.random.default_rng(1)
    scattered = Trajectory(tuple(
        replace(f, world_from_cam=perturb_pose(f.world_from_cam, 0.5, 0.01, rng))
        for f in drifted.frames), "synthetic", "lamar")
    j = judge_run(measurements(truth, scattered), RunConfig())
    se = j.shared.summary()
    assert se["drift"]["status"] == "failed"
    assert se["registration"]["status"] != "failed", se["registration"]["message"]
    flagged = {f["frame_id"] for f in se["drift"]["per_frame"] if f["flagged"]}
    assert flagged <= set(ids) and flagged <= set(j.shared.registration.frames_left_out)
    outside = [r for r in j.rows() if r["frame_id"] not in set(ids)]
    assert all(r["verdict"] == "PASS" for r in outside), [r["reason"] for r in outside]


def _with_edges(ms: list[FrameMeasurement], err: float) -> list[FrameMeasurement]:
    """``ms`` with a geometric-edge path of corner error ``err`` (the raw path of
    ``measurements(relative=True)`` has too few inliers: the edges are the frame's own
    evidence, as on a colourless mesh)."""
    from dataclasses import replace

    edges = replace(_path("raw", err), kind="edges", method="edges")
    return [replace(m, edges=edges) for m in ms]


def test_frames_failed_by_the_registration_check_keep_their_own_verdict(truth):
    """A shared move below the per-frame threshold: the registration check fails every frame,
    yet each frame's own evidence (its edges; the raw path has too few inliers) passes
    (``Judgement.own_verdict``), so such frames still serve as references for relative paths
    (``enhance.refs.absolute_passes``: frame and reference carry the shared error alike; the
    reference pass of a run whose every verdict was FAIL had taken them all away)."""
    from pgt_check.enhance.refs import absolute_passes

    moved = _move(truth, 0.5, 0.03)
    j = judge_run(_with_edges(measurements(truth, moved, relative=True), 5.0), RunConfig())
    assert j.shared.summary()["registration"]["status"] == "failed"
    assert all(f.verdict == "FAIL" and f.reason.startswith("registration") for f in j.frames)
    assert all(f.judgement.raw_verdict == "UNVERIFIABLE" for f in j.frames)
    assert all(f.judgement.own_verdict == "PASS" for f in j.frames)
    assert absolute_passes(j) == {f.frame_id for f in j.frames} - set(j.shared.left_out)
    # frames whose own edges are off by more than the threshold do not
    off = judge_run(_with_edges(measurements(truth, moved, relative=True), 40.0), RunConfig())
    assert all(f.judgement.own_verdict == "FAIL" for f in off.frames)
    assert absolute_passes(off) == set()
