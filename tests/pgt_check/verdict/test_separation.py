"""Each evidence path's separating power on the run (``pgt_check.verdict.separation``, issue
#38 item 5): frames moved by a known amount and measured again; a path whose error does not
follow the pose decides no frame (``path_cannot_separate``)."""

from __future__ import annotations

import json
import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from pgt_check.config import RunConfig, VerdictConfig
from pgt_check.enhance.base import Evidence
from pgt_check.measure import FrameMeasurement, PathMeasurement
from pgt_check.verdict import judge_run
from pgt_check.verdict.separation import (
    ALPHA,
    CANNOT_SEPARATE,
    FAILED,
    MIN_PAIRS,
    MOVE_MULTIPLE,
    NOT_TESTED,
    PASSED,
    Probe,
    load_probes,
    path_separation,
    probe_plan,
    rank_probabilities,
    rank_sum_p,
    save_probes,
)

ROOT = Path(__file__).resolve().parents[3]
W, H, F = 320, 240, 288.0


def _path(kind, err, inliers=120, evidence=Evidence.ABSOLUTE):
    return PathMeasurement(
        kind=kind, method=kind, evidence=evidence, n_kpts_render=500, n_kpts_photo=500,
        n_matches=2 * inliers, n_inliers=inliers, inlier_ratio=0.5, reason="",
        photo_from_render=tuple(map(tuple, np.eye(3))), corner_error_px=err,
    )


def _frame(fid, raw=None, enhanced=None, verdict_path="raw"):
    return FrameMeasurement(
        frame_id=fid, timestamp=0, image_path=f"{fid}.png", width=W, height=H,
        center=(0.0, 0.0, 0.0), coverage=0.8, intrinsics=(F, F, (W - 1) / 2, (H - 1) / 2),
        raw=None if raw is None else _path("raw", raw, 30),
        enhanced=None if enhanced is None else _path("enhanced", enhanced, 150),
        verdict_path=verdict_path,
    )


def _run(n=20, seed=0):
    """A run of ``n`` frames, 40 % wrong (true image error 12-40 px, threshold 8 px): the raw
    path measures the true error (+ noise), the enhanced path (more inliers, so it is each
    frame's ``verdict_path``) reports an error unrelated to the pose. Returns (measurements,
    probes, wrong ids): each frame also measured at +/- a rotation moving the image by
    ``MOVE_MULTIPLE`` x the threshold, as each path would see it."""
    rng = np.random.default_rng(seed)
    cfg = VerdictConfig()
    thr = cfg.threshold_for(W, H)
    wrong = set(rng.choice(n, int(0.4 * n), replace=False).tolist())
    ms, true = [], {}
    for i in range(n):
        e = rng.uniform(12, 40) * _unit(rng) if i in wrong else rng.normal(0, 1.0, 2)
        true[f"f{i}"] = e
        ms.append(_frame(f"f{i}", raw=float(np.linalg.norm(e + rng.normal(0, 0.5, 2))),
                         enhanced=float(rng.uniform(2, 40)), verdict_path="enhanced"))
    jobs = probe_plan(ms, cfg, 8, paths=("raw", "enhanced"))
    probes = []
    for j in jobs:
        move = j.sign * MOVE_MULTIPLE * thr * np.array([j.axis[1], -j.axis[0]])
        raw = float(np.linalg.norm(true[j.frame_id] + move + rng.normal(0, 0.5, 2)))
        m = _frame(j.frame_id, raw=raw, enhanced=float(rng.uniform(2, 40)),
                   verdict_path="enhanced")
        probes.append(Probe(j, m))
    return ms, probes, {f"f{i}" for i in wrong}


def _unit(rng):
    v = rng.normal(size=2)
    return v / np.linalg.norm(v)


def test_rank_sum_null_is_exact():
    """P(T <= t) for the sum of n uniform {1, 2, 3}: checked by enumeration."""
    import itertools

    for n in (1, 3, 5):
        sums = [sum(c) for c in itertools.product((1, 2, 3), repeat=n)]
        for t in range(n, 3 * n + 1):
            assert rank_sum_p(t, n) == pytest.approx(np.mean([x <= t for x in sums]))
    assert rank_sum_p(8, 8) == pytest.approx(3.0**-8)
    assert rank_sum_p(11, 8) == pytest.approx(157 / 6561)
    assert rank_sum_p(0, 0) == 1.0
    assert rank_sum_p(MIN_PAIRS + 1, MIN_PAIRS) < ALPHA  # the fewest frames can pass
    # with failures (q): the ranks' law by simulation of a path blind to the pose
    rng = np.random.default_rng(0)
    q = 0.4
    e = np.where(rng.random((200_000, 3)) < q, np.inf, rng.random((200_000, 3)))
    e = e[np.isfinite(e[:, 0])]
    r = 1 + (e[:, 1] <= e[:, 0]) + (e[:, 2] <= e[:, 0])
    assert np.bincount(r, minlength=4)[1:] / len(r) == pytest.approx(
        rank_probabilities(q), abs=0.005)
    assert rank_sum_p(8, 8, q) == pytest.approx(rank_probabilities(q)[0] ** 8)


@pytest.mark.parametrize("q", [0.0, 0.5])
def test_the_null_holds_for_a_blind_path(q):
    """Errors that do not follow the pose (heavy-tailed, the same law at every pose), and with
    q = 0.5 no alignment on half of the poses, given or moved alike: the path passes in at most
    ALPHA of 200 runs plus sampling noise (12; the test is conservative: 2 with q = 0.5). A
    null that ignored the path's failures at its own poses passed it 14 times.)"""
    cfg = VerdictConfig()
    passed = 0
    for seed in range(200):
        rng = np.random.default_rng(100 + seed)

        def blind(fid, rng=rng):
            m = _frame(fid, enhanced=float(rng.lognormal(2.5, 0.8)), verdict_path="enhanced")
            if rng.random() < q:
                m = replace(m, enhanced=replace(m.enhanced, n_inliers=5))  # no alignment
            return m

        ms = [blind(f"f{i}") for i in range(24)]
        jobs = probe_plan(ms, cfg, 8, paths=("enhanced",))
        probes = [Probe(j, blind(j.frame_id)) for j in jobs]
        sep = path_separation(ms, probes, cfg)
        passed += sep.paths[0].status == PASSED
    assert passed <= 12, passed


def test_the_test_separates_a_faithful_path_from_a_blind_one():
    """Over 20 runs (40 % of the frames wrong by 1.5-5 x the threshold, the hard case: a move
    can bring a wrong frame closer): the raw path, which measures the pose, passes in at least
    90 %; the blind enhanced path fails in at least 90 % (alpha 5 %)."""
    raw_passed = enh_failed = 0
    for seed in range(20):
        ms, probes, _ = _run(seed=seed)
        by = {p.path: p for p in path_separation(ms, probes, VerdictConfig()).paths}
        raw_passed += by["raw"].status == PASSED
        enh_failed += by["enhanced"].status == FAILED
        assert by["raw"].n_frames == by["enhanced"].n_frames == 8
    assert raw_passed >= 18 and enh_failed >= 18, (raw_passed, enh_failed)


def test_a_path_whose_error_does_not_follow_the_pose_is_barred():
    """The enhanced path reports errors unrelated to the pose: before, it decided every frame
    (more inliers), and its PASS / FAIL were chance. It fails the test; the raw path, which
    measures the pose (40 % of the frames wrong themselves), passes it and decides."""
    ms, probes, wrong = _run(seed=1)
    cfg = RunConfig()
    cfg = replace(cfg, run_checks=replace(cfg.run_checks, enabled=False))
    sep = path_separation(ms, probes, cfg.verdict)
    by = {p.path: p for p in sep.paths}
    assert by["raw"].status == PASSED and by["enhanced"].status == FAILED, sep
    assert by["raw"].move_px == pytest.approx(MOVE_MULTIPLE * cfg.verdict.threshold_for(W, H))
    before = judge_run(ms, cfg)
    assert {f.judgement.decided_by for f in before.frames} == {"enhanced"}
    chance = [f for f in before.frames if (f.verdict == "PASS") == (f.frame_id in wrong)]
    assert chance  # verdicts the blind path got wrong
    after = judge_run(ms, cfg, probes)
    assert after.separation is not None and after.separation.barred.keys() == {"enhanced"}
    assert {f.judgement.decided_by for f in after.frames} == {"raw"}
    # the raw path decides: every wrong frame FAILs, every correct one PASSes
    for f in after.frames:
        assert f.verdict == ("FAIL" if f.frame_id in wrong else "PASS"), f.judgement
    summary = after.summary_extra()["path_separation"]
    assert summary["barred"] == ["enhanced"]
    assert summary["paths"]["enhanced"]["status"] == FAILED


def test_a_barred_path_with_nothing_else_makes_its_frames_unverifiable():
    """Where the barred path is the only one with a result the frame is UNVERIFIABLE with
    the reason that says why: not a PASS, not a FAIL."""
    ms, probes, _ = _run(seed=4)
    cfg = RunConfig()
    cfg = replace(cfg, run_checks=replace(cfg.run_checks, enabled=False))
    lone = replace(ms[0], raw=None, frame_id="lone")
    res = judge_run([*ms, lone], cfg, probes)
    f = res.frames[-1]
    assert f.verdict == "UNVERIFIABLE" and f.reason.startswith(CANNOT_SEPARATE), f.reason
    assert "enhanced path" in f.reason
    assert res.separation.barred_frames == 1


def test_too_few_frames_is_not_tested_and_keeps_deciding():
    ms, probes, _ = _run(n=20, seed=5)
    few = [p for p in probes if p.job.frame_id in {p.job.frame_id for p in probes[:6]}]
    sep = path_separation(ms, few, VerdictConfig())
    assert {p.status for p in sep.paths} == {NOT_TESTED} and not sep.barred


def test_the_plan_probes_every_path_on_shared_frames_without_looking_at_errors():
    ms, _, _ = _run(n=30, seed=6)
    cfg = VerdictConfig()
    jobs = probe_plan(ms, cfg, 8)
    # every path with enough frames, also the raw path that decides no frame here (it may
    # once the enhanced path is barred)
    assert {p for j in jobs for p in j.paths} == {"raw", "enhanced"}
    both = probe_plan(ms, cfg, 8, paths=("raw", "enhanced"))
    assert [j.key for j in both] == [j.key for j in jobs]
    assert len({j.frame_id for j in both}) == 8  # one set of frames serves both paths
    assert all(set(j.paths) == {"raw", "enhanced"} for j in both)
    assert len(both) == 16 and {j.sign for j in both} == {1, -1}
    # the move: MOVE_MULTIPLE x the threshold at the image centre, about an in-plane axis
    j = both[0]
    assert F * math.tan(math.radians(abs(j.angle_deg))) == pytest.approx(
        MOVE_MULTIPLE * cfg.threshold_for(W, H))
    assert j.axis[2] == 0.0 and math.hypot(j.axis[0], j.axis[1]) == pytest.approx(1.0)
    # the same errors reshuffled give the same frames (chosen without looking at them)
    shuffled = [replace(m, enhanced=replace(m.enhanced, corner_error_px=1.0)) for m in ms]
    assert [x.key for x in probe_plan(shuffled, cfg, 8)] == [x.key for x in jobs]
    assert probe_plan(ms, cfg, 0) == []


def test_probes_round_trip_through_the_run_folder(tmp_path):
    ms, probes, _ = _run(seed=7)
    save_probes(tmp_path, probes, "fp1")
    back = load_probes(tmp_path)
    assert [p.job for p in back] == [p.job for p in probes]
    assert [p.measurement.raw.corner_error_px for p in back] == \
        [p.measurement.raw.corner_error_px for p in probes]
    assert load_probes(tmp_path, "other") == []
    assert json.loads((tmp_path / "separation_probes.json").read_text())["version"] == 1


# -- end to end on a generated scene -----------------------------------------------------------
class _BlindEnhancer:
    """An enhanced path that cannot see the pose: the 'enhanced render' is the reference
    photo itself, so its match with the photo measures the offset between the two photos,
    whatever the pose checked (absolute evidence, as MaRINeR's)."""

    name = "reproject"
    evidence = Evidence.ABSOLUTE
    detail_short_side = None

    @classmethod
    def from_config(cls, config):
        return cls()

    def enhance(self, view, reference, renderer):
        from pgt_check.enhance.base import EnhancedImage

        img = reference.photo
        h, w = view.render.rgb.shape[:2]
        if img.shape[:2] != (h, w):
            import cv2

            img = cv2.resize(img, (w, h))
        return EnhancedImage(img.astype(np.float32), np.ones((h, w), bool))


@pytest.mark.slow
def test_end_to_end_a_blind_enhanced_path_is_barred_on_a_generated_scene(tmp_path, monkeypatch):
    """The boxes scene (generated, sample_data/boxes), 12 frames, 4 of them moved by 2-4
    deg; the enhanced path replaced by one that cannot see the pose (it has more inliers than
    the raw render, so it was every frame's deciding path). The run measures moved copies,
    bars the blind path (summary.json ``path_separation``), keeps the geometric-edge path,
    which decides instead, and no frame is decided by the blind path; ``pgt-check report`` judges the stored probes
    again the same way."""
    import pgt_check.enhance.reproject as reproject
    from pgt_check.cli import main
    from pgt_check.io import read_trajectory
    from pgt_check.io.lamar_write import write_lamar
    from pgt_eval import perturb_pose

    # the registry names the class by module path: the serial run builds this one
    monkeypatch.setattr(reproject, "ReprojectEnhancer", _BlindEnhancer)
    src = ROOT / "sample_data" / "boxes"
    traj = read_trajectory(src / "trajectories.txt")
    rng = np.random.default_rng(0)
    frames = list(traj.frames[:12])
    wrong = {1, 4, 7, 10}
    for i in wrong:
        frames[i] = frames[i].with_pose(perturb_pose(frames[i].world_from_cam,
                                                     rng.uniform(2, 4), 0.05, rng))
    from pgt_check.types import Trajectory

    write_lamar(Trajectory(tuple(frames), traj.source, traj.format), tmp_path / "in")
    out = tmp_path / "out"
    rc = main([str(tmp_path / "in" / "trajectories.txt"), "--mesh", str(src / "boxes.ply"),
               "--out", str(out), "--enhance", "always", "--enhance-method", "reproject",
               "-q"])
    assert rc in (0, 1)
    summary = json.loads((out / "summary.json").read_text())
    sep = summary["path_separation"]
    assert sep["paths"]["enhanced"]["status"] == FAILED, sep
    assert sep["paths"]["edges"]["status"] == PASSED, sep
    # the blind path's points do not pull the run-level checks either: its random matches
    # would read as a misregistered trajectory
    assert summary["shared_errors"]["registration"]["status"] != "failed", summary
    import csv

    rows = list(csv.DictReader((out / "frames.csv").open()))
    assert all(r["decided_by"] != "enhanced" or r["verdict"] == "UNVERIFIABLE" for r in rows)
    assert any(r["verdict_path"] == "enhanced" for r in rows)  # it had more inliers
    # the geometric-edge path decides: the moved frames FAIL, the others PASS
    assert sum(r["decided_by"] == "edges" for r in rows) >= 10
    for i, r in enumerate(rows):
        if r["decided_by"] == "edges":
            assert r["verdict"] == ("FAIL" if i in wrong else "PASS"), r
    html = (out / "report.html").read_text()
    assert "Can each path tell right from wrong on this run?" in html
    assert "CANNOT SEPARATE" in html
    assert any(s.startswith("the enhanced path CANNOT SEPARATE") for s in sep["sentences"])
    # pgt-check report judges the stored probes again
    assert main(["report", str(out)]) in (0, 1)
    again = json.loads((out / "summary.json").read_text())["path_separation"]
    assert again["barred"] == ["enhanced"]
