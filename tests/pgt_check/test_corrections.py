"""Corrected poses: render -> match -> PnP rounds for FAIL frames, and the files they feed."""

from __future__ import annotations

import csv
import json
import xml.etree.ElementTree as ET

import numpy as np
import pytest

from pgt_check.cli import main
from pgt_check.geometry.transforms import axis_angle_to_rotmat, make_rigid, pose_difference
from pgt_check.io import read_trajectory


@pytest.fixture(scope="module")
def corrected_run(tmp_path_factory, sample_scene):
    """Frames 0-4 of the sample: frame 3 carries a documented 3.5 deg error (perturbed.txt)."""
    out = tmp_path_factory.mktemp("corr") / "out"
    rc = main([str(sample_scene / "trajectories.txt"), "--mesh", str(sample_scene / "mesh.glb"),
               "--out", str(out), "--limit", "5", "--report-details", "0", "-q"])
    return rc, out


def _truth_3(sample_scene):
    f = read_trajectory(sample_scene / "trajectories.txt").by_id()["3/cam0"]
    # perturbed.txt: stored = true @ [R(y, 3.5 deg) | 0]
    return f.world_from_cam @ np.linalg.inv(make_rigid(axis_angle_to_rotmat(
        np.array([0.0, 1.0, 0.0]), 3.5), np.zeros(3)))


def test_fail_frame_is_corrected_to_the_truth(corrected_run, sample_scene):
    rc, out = corrected_run
    assert rc == 1  # the gate fails (frame 3 FAILs) ...
    fixed = read_trajectory(out / "corrected_trajectory.txt", "lamar",
                            sensors=sample_scene / "sensors.txt",
                            images=sample_scene / "images.txt")
    given = read_trajectory(sample_scene / "trajectories.txt").by_id()
    by_id = fixed.by_id()
    assert len(fixed) == len(given)  # every frame is written, not only the checked ones
    dt, dr = pose_difference(by_id["3/cam0"].world_from_cam, _truth_3(sample_scene))
    assert dr < 0.1 and dt < 0.01  # ... and the corrected pose is within 0.1 deg / 1 cm
    for fid in ("0/cam0", "1/cam0", "4/cam0", "20/cam0"):  # PASS and unchecked: unchanged
        np.testing.assert_allclose(by_id[fid].world_from_cam, given[fid].world_from_cam,
                                   atol=1e-12)
    bad = [ln for ln in (out / "bad_frames.txt").read_text().splitlines()
           if ln and not ln.startswith("#")]
    assert bad == ["3/cam0"]


def test_correction_columns_in_csv_junit_report_and_summary(corrected_run):
    _, out = corrected_run
    rows = {r["frame_id"]: r for r in csv.DictReader(open(out / "frames.csv"))}
    r3 = rows["3/cam0"]
    assert abs(float(r3["corr_drot_deg"]) - 3.5) < 0.1
    assert float(r3["corr_sigma_rot_deg"]) < 0.1 and r3["corr_applied"] == "True"
    assert float(r3["corr_corner_error_px"]) < float(r3["threshold_px"])
    assert rows["0/cam0"]["corr_drot_deg"] == ""  # PASS frames are not corrected by default
    case = next(c for c in ET.parse(out / "junit.xml").iter("testcase")
                if c.get("name") == "3/cam0")
    assert not list(case.iter("property"))  # schema-valid: no per-testcase properties
    assert "correction 3.5" in case.find("failure").text
    assert "correction 3.5" in case.find("system-out").text
    html = (out / "report.html").read_text()
    assert "corr_drot_deg" in html and "corr. rot [deg]" in html
    summary = json.loads((out / "summary.json").read_text())
    assert summary["corrections"]["applied"] == 1 and summary["corrections"]["format"] == "lamar"


def test_report_rebuild_keeps_corrections_and_rejudges_every_verdict_setting(corrected_run):
    _, out = corrected_run
    # a looser threshold: frame 3 PASSes; the stored correction stays in its row
    assert main(["report", str(out), "--threshold-px", "30", "--min-inlier-ratio", "0.0"]) == 0
    rows = {r["frame_id"]: r for r in csv.DictReader(open(out / "frames.csv"))}
    assert rows["3/cam0"]["verdict"] == "PASS" and rows["3/cam0"]["corr_drot_deg"] != ""
    # min_inliers above any count: every frame UNVERIFIABLE; a run where nothing was verified
    # fails the gate whatever the limits (fail closed), and the outputs say so
    assert main(["report", str(out), "--min-inliers", "100000",
                 "--max-unverifiable-fraction", "1.0"]) == 1
    rows = list(csv.DictReader(open(out / "frames.csv")))
    assert {r["verdict"] for r in rows} == {"UNVERIFIABLE"}
    assert "no frame was verified" in json.loads((out / "summary.json").read_text())["gate"][
        "explanation"]
    # re-judged settings are kept in config.json (min_inliers still 100000 here) until changed
    assert main(["report", str(out), "--min-inliers", "15", "--threshold-px", "8"]) == 1
    rows = {r["frame_id"]: r for r in csv.DictReader(open(out / "frames.csv"))}
    assert rows["3/cam0"]["verdict"] == "FAIL" and rows["0/cam0"]["verdict"] == "PASS"


def test_correct_none_writes_input_poses(tmp_path, sample_scene):
    out = tmp_path / "o"
    rc = main([str(sample_scene / "trajectories.txt"), "--mesh", str(sample_scene / "mesh.glb"),
               "--out", str(out), "--limit", "4", "--correct", "none", "--report-details", "0",
               "--enhance", "never", "-q"])
    assert rc == 1
    assert not (out / "corrected_trajectory.txt").exists()
    assert "corr_drot_deg" in (out / "frames.csv").read_text().splitlines()[0]


@pytest.mark.slow
@pytest.mark.shared_data
def test_real_data_correction_7scenes(shared_data):
    """One 7-Scenes frame with an injected 2 deg / 4 cm error converges to where its own pose
    converges (the D-SLAM poses fit the photos only to ~8 px, see the data README, so the
    fixed point of render/photo matching is not the given pose itself)."""
    from pgt_check.config import RunConfig
    from pgt_check.correct.frames import correct_frame
    from pgt_check.measure import FrameChecker
    from pgt_eval import perturb_pose

    d = shared_data / "7scenes_redkitchen"
    f = read_trajectory(d / "trajectories.txt", sensors=d / "sensors.txt")[10]
    bad = f.with_pose(perturb_pose(f.world_from_cam, 2.0, 0.04, np.random.default_rng(0)))
    cfg = RunConfig.from_dict({"input": {"mesh": str(d / "mesh.ply")},
                               "enhance": {"mode": "never"}})
    checker = FrameChecker(cfg)
    try:
        m = checker.measure(bad)
        c = correct_frame(checker, bad, m, cfg.correct)
        base = correct_frame(checker, f, None, cfg.correct)
    finally:
        checker.close()
    assert c.success and base.success
    dt, dr = pose_difference(c.pose, base.pose)
    dt0, dr0 = pose_difference(bad.world_from_cam, base.pose)
    # raw SIFT finds few inliers on this TSDF mesh: an applied correction (verified by the
    # raw render or, measured again at the corrected pose, by the geometric edges) lands
    # nearer the fixed point than the input did; along the rotation / translation trade-off
    # of these views it can stay 1.4 of 2.3 deg away (reports/pose_trade_off.md), which its
    # stated uncertainty covers; otherwise it says why it was not applied
    if c.applied:
        assert c.verified_by in ("raw", "edges")
        assert dr < 0.75 * dr0 and dt < 0.75 * dt0, (dr, dr0, dt, dt0)
    else:
        assert c.reason in ("uncertain", "not_verified")
    assert dr <= 2 * np.hypot(c.sigma_rot_deg, base.sigma_rot_deg)


def test_corrections_stop_at_their_time_budget(tmp_path, monkeypatch):
    """At most ``correct.budget`` x the main pass's measuring time: the frames left are not
    corrected (reason ``time_limit``) and the summary says why (issue #28)."""
    import pgt_check.correct.frames as frames_mod
    from pgt_check.config import RunConfig
    from pgt_check.correct.correction import Correction
    from pgt_check.measure import MeasureReason, failed_measurement
    from pgt_check.measure.record import Timings
    from pgt_check.types import Camera, Frame, Trajectory
    from pgt_check.verdict.judgement import Judgement, Verdict
    from pgt_check.verdict.result import FrameResult, RunResult

    cam = Camera.pinhole(64, 48, 50.0, 50.0, 31.5, 23.5)
    traj = Trajectory(tuple(Frame(f"f{i}", cam, np.eye(4), timestamp=float(i))
                            for i in range(10)), "synthetic", "lamar")
    ms = [failed_measurement(f, MeasureReason.NONE).with_timings(Timings(total=1.0))
          for f in traj.frames]  # main pass: 10 s
    result = RunResult(tuple(
        FrameResult(m, Judgement(Verdict.FAIL, "corner_error", "absolute", "FAIL", ""), 4.0)
        for m in ms), None)
    now = [0.0]

    def fake_correct(checker, frame, m, correct, threshold_px=None, references=()):
        now[0] += 4.0  # each correction takes 4 s
        return Correction(frame.frame_id, True, "", rounds=1)

    class Checker:
        def close(self):
            pass

    monkeypatch.setattr(frames_mod, "correct_frame", fake_correct)
    config = RunConfig.from_dict({"input": {"trajectory": "t", "mesh": "m"},
                                  "correct": {"budget": 2.0}})  # 20 s
    corrections, summary = frames_mod.correct_run(traj, ms, result, config, Checker, tmp_path,
                                                  clock=lambda: now[0])
    c = summary.to_json()  # summary.json -> corrections
    # 5 frames (20 s) fit; a sixth (24 s) would exceed the budget
    assert c["attempted"] == 5 and c["not_attempted"] == 5
    assert c["stopped"].startswith("time limit: 5 frame(s) took 20.0 s of the 20.0 s budget")
    assert [c.reason for c in corrections.values()].count("time_limit") == 5
    # 0: no bound
    config = RunConfig.from_dict({"input": {"trajectory": "t", "mesh": "m"},
                                  "correct": {"budget": 0}})
    _, summary = frames_mod.correct_run(traj, ms, result, config, Checker, tmp_path,
                                        clock=lambda: now[0])
    assert summary.attempted == 10 and summary.stopped is None


def _blurred_copy(mesh_glb, out, sigma):
    """The sample mesh with its textures blurred (Gaussian, ``sigma`` texture px): a scan's
    vertex colours, averaged over views, are blurred where the photos are sharp."""
    import trimesh
    from PIL import ImageFilter

    scene = trimesh.load(mesh_glb)
    for g in scene.geometry.values():
        mat = g.visual.material
        mat.baseColorTexture = mat.baseColorTexture.filter(ImageFilter.GaussianBlur(sigma))
    path = out / "blurred.glb"
    scene.export(path)
    return path


def _sample_truth(sample_scene):
    """The sample trajectory with its documented perturbations (perturbed.txt) undone."""
    from pgt_check.geometry.transforms import invert_rigid
    from pgt_check.types import Trajectory

    traj = read_trajectory(sample_scene / "trajectories.txt")
    offsets = {}
    for line in (sample_scene / "perturbed.txt").read_text().splitlines():
        if line.startswith("#") or not line.strip():
            continue
        f = [x.strip() for x in line.split(",")]
        rot = axis_angle_to_rotmat(np.array(list(map(float, f[2:5]))), float(f[1]))
        offsets[f[0]] = make_rigid(rot, np.array(list(map(float, f[5:8]))))
    return Trajectory(tuple(fr.with_pose(fr.world_from_cam @ invert_rigid(offsets[fr.frame_id]))
                            if fr.frame_id in offsets else fr for fr in traj),
                      traj.source, traj.format)


def _wrong_run(truth, indices, error, mesh, tmp_path, frames_mode, seed):
    """The frames ``indices`` of ``truth`` moved by ``error`` (deg, scene units; random axes and
    directions), measured and judged with the defaults (corrections of ``frames_mode``, no
    time budget): (trajectory, config, measurements, run result, frame id -> error)."""
    from pgt_check.config import RunConfig
    from pgt_check.measure import FrameChecker, pick_references
    from pgt_check.types import Trajectory
    from pgt_check.verdict import judge_run
    from pgt_eval import perturb_pose

    rng = np.random.default_rng(seed)
    frames = list(truth.frames)
    injected = {}
    for i in indices:
        f = frames[i]
        frames[i] = f.with_pose(perturb_pose(f.world_from_cam, *error, rng))
        injected[f.frame_id] = error
    traj = Trajectory(tuple(frames), truth.source, truth.format)
    cfg = RunConfig.from_dict({"input": {"mesh": str(mesh)}, "out": str(tmp_path),
                               "correct": {"frames": frames_mode, "budget": 0}})
    checker = FrameChecker(cfg, pick_references(traj, traj.frames, cfg))
    try:
        ms = [checker.measure(f) for f in traj.frames]
    finally:
        checker.close()
    return traj, cfg, ms, judge_run(ms, cfg), injected


def test_corrections_on_a_blurred_scan_come_within_30_percent(tmp_path, sample_scene):
    """Issue #38 item 4 on generated data: a mesh whose colours are blurred (as a TSDF scan's:
    7-Scenes) gives the raw render few matches, and each round's PnP on them jumped around its
    fixed point (before: 1 of 4 frames within 30 % of its 2.5 deg / 12 cm error, 0.4-1.4 deg
    left, yet applied). The rounds' correspondences pooled into one PnP, and the render also
    enhanced with a neighbour the run vouches for, bring every wrong frame back to within 30 %
    of its error; a wrong neighbour (frames 9 and 10 both wrong) never serves as a reference."""
    from pgt_check.correct.frames import correct_run, vouched_references
    from pgt_check.measure import build_frame_checker

    mesh = _blurred_copy(sample_scene / "mesh.glb", tmp_path, 4.0)
    truth = _sample_truth(sample_scene)
    # 2.5 deg + 12 cm: 3 % of the ~4 m scene depth
    traj, cfg, ms, result, injected = _wrong_run(truth, (3, 9, 10, 15, 21), (2.5, 0.12), mesh,
                                                 tmp_path, "fail", seed=0)
    verdicts = {f.frame_id: f.verdict for f in result.frames}
    assert all(verdicts[fid] == "FAIL" for fid in injected)
    refs = vouched_references(traj, result.frames, {m.frame_id: m for m in ms}, cfg,
                              list(injected))
    for fid, rs in refs.items():
        assert rs and all(verdicts[r.frame_id] == "PASS" for r in rs), fid
    corr, _ = correct_run(traj, ms, result, cfg, lambda: build_frame_checker(cfg, None),
                          tmp_path)
    given = truth.by_id()
    for fid, (rot, t) in injected.items():
        c = corr[fid]
        assert c.success, (fid, c.reason)
        dt, dr = pose_difference(given[fid].world_from_cam, c.pose)
        assert dr <= 0.3 * rot and dt <= 0.3 * t, (fid, dr, dt, c, [r.frame_id for r in refs[fid]])
        if c.applied:  # an applied correction's stated uncertainty covers its error
            assert dr <= 3 * max(c.sigma_rot_deg, 0.05), (fid, dr, c.sigma_rot_deg)


def test_relative_fallback_needs_a_reference_the_run_vouches_for(monkeypatch, sample_scene):
    """Where the raw rounds cannot correct a frame (a colourless mesh), the measurement's
    one-shot PnP through its enhanced path is written as a correction only when the run
    vouches for the reference that path used: a wrong or unchecked reference's pose error
    would be written into the corrected trajectory (colourless 7-Scenes, judged where nothing
    PASSes, applied 10 such corrections, 6 further off than the input)."""
    import pgt_check.correct.frames as cf
    from pgt_check.config import RunConfig
    from pgt_check.correct.correction import Correction
    from pgt_check.enhance.base import Evidence
    from pgt_check.measure.record import FrameMeasurement, PathMeasurement, PoseEstimate

    truth = _sample_truth(sample_scene)
    frame, ref, other = truth.frames[3], truth.frames[4], truth.frames[5]
    calls = []

    def failing_refine(checker, f, start=None, **kw):
        calls.append((start is None, tuple(r.frame_id for r in kw["references"])))
        return Correction(f.frame_id, False, "too_few_pnp_inliers")

    monkeypatch.setattr(cf, "refine_pose", failing_refine)
    estimate = np.array(frame.world_from_cam, float)
    estimate[:3, 3] += 0.05

    def measurement(n_inliers):
        enhanced = PathMeasurement("enhanced", "reproject", Evidence.RELATIVE, 500, 500, 200,
                                   n_inliers, 0.5, "", reference_id=ref.frame_id)
        pose = PoseEstimate(n_inliers, "", 0.05, 0.0, tuple(map(tuple, estimate)))
        return FrameMeasurement(frame.frame_id, None, None, 640, 480, (0.0, 0.0, 0.0),
                                enhanced=enhanced, verdict_path="enhanced", pose=pose)

    c = RunConfig().correct
    got = cf.correct_frame(None, frame, measurement(120), c, references=(ref, other))
    assert got.success and got.applied and got.reason == "relative_evidence"
    assert np.allclose(got.pose, estimate)
    assert calls == [(False, (ref.frame_id, other.frame_id)), (True, (ref.frame_id,
                                                                      other.frame_id))]
    # the reference that path used is not vouched for (another one is): not written
    got = cf.correct_frame(None, frame, measurement(120), c, references=(other,))
    assert not got.success and got.reason == "too_few_pnp_inliers"
    # nothing vouched (a run-level check failed every frame): not written
    assert not cf.correct_frame(None, frame, measurement(120), c, references=()).success
    # vouched, but too few PnP inliers behind the estimate
    few = cf.MIN_RELATIVE_PNP_INLIERS - 1
    assert not cf.correct_frame(None, frame, measurement(few), c, references=(ref,)).success


def test_the_rounds_take_the_vouched_references_in_turn(monkeypatch, sample_scene):
    """Each reference places its photo on the mesh by its own pose, whose error moves the
    correction: the default rounds use every one of the up to ``CORRECTION_REFERENCES``
    references once (one enhancement per round), so no single reference decides."""
    import pgt_check.correct.pose as P
    from pgt_check.config import RunConfig
    from pgt_check.correct.frames import CORRECTION_REFERENCES

    refs = read_trajectory(sample_scene / "trajectories.txt").frames[:CORRECTION_REFERENCES]
    assert len(refs) == CORRECTION_REFERENCES
    seen = []

    def fake_round(target, pose, references=()):
        seen.append(tuple(r.frame_id for r in references))
        moved = np.array(pose, float)
        moved[0, 3] += 0.01  # every round moves: none stops the rounds early
        return P._Round(1.0, moved, "", 50, np.zeros((0, 3)), np.zeros((0, 2)),
                        np.ones((4, 4)), None)

    monkeypatch.setattr(P, "_round", fake_round)
    rounds = RunConfig().correct.rounds
    done = P._run_rounds(None, np.eye(4), rounds, refs)
    assert done.n_done == rounds and len(done.done) == rounds
    used = [s[0] for s in seen]
    assert all(len(s) == 1 for s in seen)
    assert set(used) == {r.frame_id for r in refs}  # every reference once at least
    assert used[:CORRECTION_REFERENCES] == [r.frame_id for r in refs]


def test_rounds_too_few_for_a_pnp_alone_are_solved_together(monkeypatch, sample_scene):
    """A textureless photo gives each round fewer matches than a PnP needs (12-32 on the
    generated scans, where corrections then failed with ``too_few_pnp_inliers``): the next
    reference is matched at the same pose and the rounds there solved together, and the
    pooled pose is the photo's."""
    import pgt_check.correct.pose as P
    from pgt_check.config import RunConfig
    from pgt_check.geometry.transforms import make_rigid

    cfg = RunConfig()
    frames = read_trajectory(sample_scene / "trajectories.txt").frames
    cam, truth = frames[0].camera, np.asarray(frames[0].world_from_cam, float)
    rng = np.random.default_rng(0)
    pts_cam = np.column_stack([rng.uniform(-1.5, 1.5, 64), rng.uniform(-1, 1, 64),
                               rng.uniform(3, 6, 64)])
    world = pts_cam @ truth[:3, :3].T + truth[:3, 3]
    fx, fy = cam.focal
    cx, cy = cam.principal_point
    pix = np.column_stack([fx * pts_cam[:, 0] / pts_cam[:, 2] + cx,
                           fy * pts_cam[:, 1] / pts_cam[:, 2] + cy])
    few = cfg.pose.min_inliers - 4  # per round: too few for a PnP of its own
    seen = []

    def fake_round(target, pose, references=()):
        k = len(seen)
        seen.append(references[0].frame_id)
        sel = slice(k * few, (k + 1) * few)
        return P._Round(20.0, None, "too_few_pnp_inliers", few, world[sel], pix[sel],
                        np.ones((4, 4)), cam)

    class _Target:
        checker = type("C", (), {"config": cfg})()

    monkeypatch.setattr(P, "_round", fake_round)
    start = truth @ make_rigid(axis_angle_to_rotmat(np.array([0.0, 1.0, 0.0]), 2.0),
                               np.array([0.05, 0.0, 0.0]))
    refs = frames[1:5]
    done = P._run_rounds(_Target(), start, 4, refs)
    assert seen == [r.frame_id for r in refs]  # the rounds went on after a failed PnP
    assert done.last is not None and len(done.done) == 2  # rounds 1+2 and 3+4 together
    dt, dr = pose_difference(truth, done.pose)
    assert dr < 0.05 and dt < 0.005, (dr, dt)
    # without references left to try, a failed round still ends the rounds
    seen.clear()
    done = P._run_rounds(_Target(), start, 4, refs[:1])
    assert done.last is None and seen == [refs[0].frame_id]


def test_a_render_too_empty_to_match_is_not_retried_per_reference(monkeypatch):
    """Low coverage is the same whatever reference enhances the render: the correction stops
    at the first round (``low_coverage``) instead of rendering again per reference."""
    import pgt_check.correct.pose as P
    from pgt_check.config import RunConfig

    calls = []

    def empty_round(target, pose, references=()):
        calls.append(1)
        return P._Round(None, None, "low_coverage", 0, np.zeros((0, 3)), np.zeros((0, 2)),
                        np.zeros((4, 4)), None)

    class _Target:
        checker = type("C", (), {"config": RunConfig()})()

    monkeypatch.setattr(P, "_round", empty_round)
    done = P._run_rounds(_Target(), np.eye(4), 4, ("a", "b", "c", "d"))
    assert done.last is None and done.first.reason == "low_coverage" and len(calls) == 1


def test_a_textureless_scan_corrections_are_verified_by_measuring_again(tmp_path):
    """A textureless scan (no mesh colours; photos with objects the mesh lacks, exposure
    changes, blur): the rounds' raw render gives too few matches for a homography, so no
    correction was verified by its last round (on the generated box scans none of 24 was
    applied, though 19 were within 30 % of their error). Measured again at the corrected
    pose, the frame's own absolute evidence (the geometric edges) verifies the ones that came
    back, and the certain ones are applied: each within 30 % of its injected rotation and 50 %
    of its shift (the box scan's translation is the weaker part: 0.06 of 0.15 here), its
    stated uncertainty covering the rotation left."""
    from pgt_check.correct.frames import correct_run
    from pgt_check.measure import build_frame_checker
    from pgt_eval import make_scan_like_scene

    truth = read_trajectory(make_scan_like_scene(tmp_path / "scene", n_frames=30))
    # 2.5 deg + 15 cm: ~5 % of the ~3 m scene depth
    traj, cfg, ms, result, injected = _wrong_run(truth, (5, 15, 24), (2.5, 0.15),
                                                 tmp_path / "scene" / "scan.ply", tmp_path,
                                                 "all", seed=1)
    corr, _ = correct_run(traj, ms, result, cfg, lambda: build_frame_checker(cfg, None),
                          tmp_path)
    given = truth.by_id()
    thresholds = {f.frame_id: f.threshold_px for f in result.frames}
    applied = [fid for fid in injected if corr[fid].applied]
    assert len(applied) >= 2, {fid: corr[fid] for fid in injected}
    for fid in applied:
        c = corr[fid]
        assert c.verified_by in ("raw", "edges") and c.reason == ""
        assert c.corner_error_px is not None and c.corner_error_px <= thresholds[fid]
        dt, dr = pose_difference(given[fid].world_from_cam, c.pose)
        rot, t = injected[fid]
        assert dr <= 0.3 * rot and dt <= 0.5 * t, (fid, dr, dt, c)
        assert dr <= 3 * c.sigma_rot_deg, (fid, dr, c.sigma_rot_deg)
    # a frame verified only by measuring again says so
    assert any(corr[fid].verified_by == "edges" for fid in applied)


def test_measuring_again_verifies_only_a_pass_within_the_threshold_and_a_certain_correction(
        monkeypatch, sample_scene):
    """``_verified_again``: a correction the rounds left ``not_verified`` is applied only where
    the frame's own absolute evidence at the corrected pose PASSes within the frame's threshold
    and the correction is certain; any other correction is returned as it was."""
    from dataclasses import replace
    from types import SimpleNamespace

    import pgt_check.correct.frames as F
    from pgt_check.config import RunConfig
    from pgt_check.correct.correction import Correction
    from pgt_check.verdict.judgement import Verdict

    cfg = RunConfig()
    frame = read_trajectory(sample_scene / "trajectories.txt").frames[0]
    err = {"edges": 3.0}

    class FakeChecker:
        config = cfg
        measured = 0

        def measure(self, f):
            FakeChecker.measured += 1
            return SimpleNamespace(width=640, height=480,
                                   path=lambda name: SimpleNamespace(corner_error_px=err[name]))

    outcome = {"v": (Verdict.PASS, "", "edges")}
    monkeypatch.setattr(F, "path_outcomes", lambda m, v: {})
    monkeypatch.setattr(F, "own_outcome", lambda m, o, v: outcome["v"])
    base = Correction("0/cam0", True, "not_verified", tuple(map(tuple, np.eye(4))), 2.0, 0.1,
                      0.05, 0.01, 20.0, None, 30, 4, "pnp_raw")
    c = F._verified_again(FakeChecker(), frame, base, 8.0)
    assert c.applied and c.reason == "" and c.verified_by == "edges" and c.corner_error_px == 3.0
    # the evidence passes the default threshold but not the frame's own
    assert not F._verified_again(FakeChecker(), frame, base, 2.5).applied
    # uncertain: verified, not applied
    c = F._verified_again(FakeChecker(), frame, replace(base, sigma_rot_deg=1.5), 8.0)
    assert not c.applied and c.reason == "uncertain" and c.verified_by == "edges"
    # the evidence FAILs or is UNVERIFIABLE: unchanged
    for v in ((Verdict.FAIL, "corner_error", "edges"), (Verdict.UNVERIFIABLE, "x", "")):
        outcome["v"] = v
        assert F._verified_again(FakeChecker(), frame, base, 8.0) is base
    # verified or failed corrections are not measured again
    n = FakeChecker.measured
    for other in (replace(base, reason=""), Correction("0/cam0", False, "pnp_failed")):
        assert F._verified_again(FakeChecker(), frame, other, 8.0) is other
    assert FakeChecker.measured == n
