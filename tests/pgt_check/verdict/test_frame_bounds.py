"""Per-frame bounds (``pgt_check.verdict.frame_bounds``): which evidence points they rest on."""

from __future__ import annotations

import numpy as np
import pytest


def test_bound_rests_on_feature_points_when_they_suffice():
    """The geometric-edge points carry no parallax (their photo positions come from a 2D
    alignment model): the per-frame bound uses the raw points alone when they suffice."""
    from pgt_check.geometry.frame_accuracy import frame_accuracy
    from pgt_check.measure.record import AbsoluteEvidence
    from pgt_check.verdict.frame_bounds import FEATURE_ONLY_MIN_POINTS, bound_points

    rng = np.random.default_rng(0)
    k = np.array([[300.0, 0, 159.5], [0, 300.0, 119.5], [0, 0, 1]])
    n = 120
    pts = np.c_[rng.uniform(-1.5, 1.5, (n, 2)), rng.uniform(2.0, 6.0, n)]  # checked camera
    shift = np.array([0.15, 0.0, 0.0])  # the true camera is shifted: photo = K (p + t)

    def project(x: np.ndarray) -> np.ndarray:
        return (x @ k.T)[:, :2] / x[:, 2:3]

    raw2d = project(pts + shift) + rng.normal(0, 0.3, (n, 2))
    # edge points: the photo position from a 2D model of the motion (a shift of the image by
    # the mean displacement), no parallax
    mean_disp = (project(pts + shift) - project(pts)).mean(axis=0)
    edge2d = project(pts) + mean_disp
    both = AbsoluteEvidence(("raw", "edges"), tuple(map(tuple, np.r_[raw2d, edge2d])),
                            tuple(map(tuple, np.r_[pts, pts])), (n, n))
    p2, pc, src = bound_points(both)
    assert src == ("raw",) and len(p2) == n
    fa = frame_accuracy(p2, pc, k, 320, 240)
    assert fa.translation == pytest.approx(0.15, rel=0.1)
    pooled = frame_accuracy(np.r_[raw2d, edge2d], np.r_[pts, pts], k, 320, 240)
    assert pooled.translation < 0.9 * 0.15  # what the pooled points said: shift taken short
    few = AbsoluteEvidence(("raw", "edges"),
                           tuple(map(tuple, np.r_[raw2d[:10], edge2d])),
                           tuple(map(tuple, np.r_[pts[:10], pts])), (10, n))
    assert 10 < FEATURE_ONLY_MIN_POINTS and bound_points(few)[2] == ("raw", "edges")


def test_a_pass_is_bounded_by_the_evidence_it_rests_on():
    """Issue #38: on a textureless scan the edge path decided PASS (a few px) while the
    enhanced path (MaRINeR, absolute) had more inliers and 24-42 px of error; the bound rested
    on the feature points (40 or more: the enhanced path's) and stated the PASS frames to
    within 13 deg against a single-frame limit of 2.6 deg. The bound now rests on the paths
    that agree with the verdict: the PASS frame's bound is the edge path's, within the
    single-frame limit; the frame judged the other way (the enhanced path deciding a FAIL)
    keeps the large one."""
    from dataclasses import replace

    from pgt_check.config import RunConfig
    from pgt_check.enhance.base import Evidence
    from pgt_check.measure import FrameMeasurement, PathMeasurement
    from pgt_check.measure.record import AbsoluteEvidence
    from pgt_check.verdict import judge_run
    from pgt_check.verdict.accuracy import run_accuracy

    rng = np.random.default_rng(1)
    w, h, f = 320, 240, 288.0
    k = np.array([[f, 0, (w - 1) / 2], [0, f, (h - 1) / 2], [0, 0, 1]])

    def project(x: np.ndarray) -> np.ndarray:
        return (x @ k.T)[:, :2] / x[:, 2:3]

    def rot(deg: float, axis) -> np.ndarray:
        from pgt_check.geometry.transforms import axis_angle_to_rotmat

        return axis_angle_to_rotmat(np.asarray(axis, float), deg)

    def frame(fid: str, edges_err: float, enh_err: float, enh_inliers: int) -> FrameMeasurement:
        n = 150
        pts = np.c_[rng.uniform(-1.5, 1.5, (n, 2)), rng.uniform(3.0, 5.0, n)]
        edge2d = project(pts) + rng.normal(0, 0.5, (n, 2))  # the pose is right
        wrong = pts @ rot(6.0, rng.normal(size=3)).T  # the enhanced matches: 6 deg off
        enh2d = project(wrong) + rng.normal(0, 0.5, (n, 2))
        ev = AbsoluteEvidence(("mariner", "edges"), tuple(map(tuple, np.r_[enh2d, edge2d])),
                              tuple(map(tuple, np.r_[pts, pts])), (n, n))

        def path(kind, err, inl):
            return PathMeasurement(
                kind=kind, method=kind, evidence=Evidence.ABSOLUTE, n_kpts_render=500,
                n_kpts_photo=500, n_matches=2 * inl, n_inliers=inl, inlier_ratio=0.5,
                reason="", photo_from_render=tuple(map(tuple, np.eye(3))),
                corner_error_px=err)

        return FrameMeasurement(
            frame_id=fid, timestamp=0, image_path=f"{fid}.png", width=w, height=h,
            center=(0.0, 0.0, 0.0), coverage=0.8, camera_id="cam0",
            world_from_cam=tuple(map(tuple, np.eye(4))),
            intrinsics=(f, f, (w - 1) / 2, (h - 1) / 2),
            enhanced=path("enhanced", enh_err, enh_inliers), edges=path("edges", edges_err, 900),
            evidence=ev, verdict_path="enhanced",
        )

    cfg = RunConfig()
    cfg = replace(cfg, run_checks=replace(cfg.run_checks, enabled=False))
    # PASS by the edges (clear, 2 px), the enhanced path's weak 30 px FAIL overruled
    passing = frame("p", 2.0, 30.0, 30)
    # FAIL by the enhanced path (confident), the edge path's PASS does not count
    failing = frame("f", 2.0, 30.0, 150)
    res = judge_run([passing, failing], cfg)
    p, fl = res.frames
    assert (p.verdict, p.judgement.decided_by) == ("PASS", "edges")
    assert (fl.verdict, fl.judgement.decided_by) == ("FAIL", "enhanced")
    assert p.bound.evidence == "edges" and fl.bound.evidence == "mariner"
    limit = run_accuracy(res, None, cfg, p.threshold_px).limits.frame_deg
    assert p.bound.accuracy.rotation_bound_deg < min(1.0, limit)
    assert fl.bound.accuracy.rotation_deg == pytest.approx(6.0, rel=0.15)
    # what the bound said before (every absolute source, the features first): the enhanced
    # path's 6 deg on a PASS
    from pgt_check.verdict.frame_bounds import frame_bounds

    old = frame_bounds([passing])["p"]
    assert old.evidence == "mariner" and old.accuracy.rotation_bound_deg > limit


def test_a_frame_without_agreeing_absolute_evidence_has_no_bound():
    """A frame whose verdict rests on paths with no absolute points of their own (a
    reprojected reference) is not bounded by the points of a path that disagrees."""
    from pgt_check.measure.record import AbsoluteEvidence
    from pgt_check.verdict.frame_bounds import agreeing_paths, bound_points
    from pgt_check.verdict.judgement import Verdict

    ev = AbsoluteEvidence(("raw",), ((1.0, 2.0),), ((0.0, 0.0, 1.0),), (1,))
    assert bound_points(ev, paths=("enhanced",))[2] == ()
    assert bound_points(ev, paths=("raw", "enhanced"))[2] == ("raw",)
    outs = {"raw": (Verdict.FAIL, "x"), "enhanced": (Verdict.PASS, ""), "edges": None}
    assert agreeing_paths(outs, "enhanced") == ("enhanced",)
    assert agreeing_paths(outs, "raw") == ("raw",)
    assert agreeing_paths(outs, "") is None
    assert agreeing_paths({**outs, "raw": (Verdict.UNVERIFIABLE, "y")}, "raw") is None


def test_a_pass_whose_own_bound_exceeds_the_threshold_is_unverifiable():
    """A PASS and its 95 % bound must agree: a homography of a few matches can land within
    the threshold (here 2 px against 8 px) while the frame's points put the pose error beyond
    it (colourless 7-Scenes with MaRINeR: PASS frames with bounds of 17-110 px against 16 px).
    Such a frame is UNVERIFIABLE (bound_above_threshold); a frame whose points agree with the
    PASS stays PASS."""
    from dataclasses import replace

    from pgt_check.config import RunConfig
    from pgt_check.enhance.base import Evidence
    from pgt_check.measure import FrameMeasurement, PathMeasurement
    from pgt_check.measure.record import AbsoluteEvidence
    from pgt_check.verdict import judge_run

    w, h, f = 320, 240, 288.0
    k = np.array([[f, 0, (w - 1) / 2], [0, f, (h - 1) / 2], [0, 0, 1]])

    def frame(fid: str, off_deg: float, n: int, seed: int) -> FrameMeasurement:
        """The points say the pose is ``off_deg`` off (about a random axis) with 0.5 px noise;
        the homography says 2 px."""
        from pgt_check.geometry.transforms import axis_angle_to_rotmat

        rng = np.random.default_rng(seed)
        pts = np.c_[rng.uniform(-1.5, 1.5, (n, 2)), rng.uniform(3.0, 5.0, n)]
        moved = pts @ axis_angle_to_rotmat(rng.normal(size=3), off_deg).T
        p2 = (moved @ k.T)[:, :2] / moved[:, 2:3] + rng.normal(0, 0.5, (n, 2))
        ev = AbsoluteEvidence(("raw",), tuple(map(tuple, p2)), tuple(map(tuple, pts)), (n,))
        raw = PathMeasurement(
            kind="raw", method="render", evidence=Evidence.ABSOLUTE, n_kpts_render=500,
            n_kpts_photo=500, n_matches=2 * n, n_inliers=n, inlier_ratio=0.5, reason="",
            photo_from_render=tuple(map(tuple, np.eye(3))), corner_error_px=2.0)
        return FrameMeasurement(
            frame_id=fid, timestamp=0, image_path=f"{fid}.png", width=w, height=h,
            center=(0.0, 0.0, 0.0), coverage=0.8, camera_id="cam0",
            world_from_cam=tuple(map(tuple, np.eye(4))),
            intrinsics=(f, f, (w - 1) / 2, (h - 1) / 2), raw=raw, evidence=ev,
            verdict_path="raw")

    cfg = RunConfig()
    cfg = replace(cfg, run_checks=replace(cfg.run_checks, enabled=False))
    res = judge_run([frame("off", 3.0, 30, 0), frame("agrees", 0.0, 30, 1)], cfg)
    off, agrees = res.frames
    assert off.bound.accuracy.effect_bound_px > off.threshold_px
    assert off.verdict == "UNVERIFIABLE"
    assert off.reason.startswith("bound_above_threshold"), off.reason
    assert agrees.verdict == "PASS"
    assert agrees.bound.accuracy.effect_bound_px <= agrees.threshold_px


def test_a_pass_is_checked_against_every_point_it_rests_on():
    """A PASS by raw features and the geometric edges together: the feature points alone (many
    enough for the feature-only pose bound, but off) bound the displacement beyond the
    threshold, the precise edge points that agree with the PASS do not. The PASS is checked
    against all of them and stands (7-Scenes: edge-agreeing PASS frames were UNVERIFIABLE on a
    22-53 px bound from 29-51 raw inliers); without the edges it is UNVERIFIABLE."""
    from dataclasses import replace

    from pgt_check.config import RunConfig
    from pgt_check.enhance.base import Evidence
    from pgt_check.measure import FrameMeasurement, PathMeasurement
    from pgt_check.measure.record import AbsoluteEvidence
    from pgt_check.verdict import judge_run
    from pgt_check.verdict.frame_bounds import FEATURE_ONLY_MIN_POINTS

    w, h, f = 320, 240, 288.0
    k = np.array([[f, 0, (w - 1) / 2], [0, f, (h - 1) / 2], [0, 0, 1]])
    rng = np.random.default_rng(3)
    n_raw, n_edge = FEATURE_ONLY_MIN_POINTS + 5, 200

    def cloud(n: int) -> np.ndarray:
        return np.c_[rng.uniform(-1.5, 1.5, (n, 2)), rng.uniform(3.0, 5.0, n)]

    def project(x: np.ndarray) -> np.ndarray:
        return (x @ k.T)[:, :2] / x[:, 2:3]

    raw_pts, edge_pts = cloud(n_raw), cloud(n_edge)
    # the features alone put the pose 3 deg off (10-15 px here); the precise edges, none
    from pgt_check.geometry.transforms import axis_angle_to_rotmat

    moved = raw_pts @ axis_angle_to_rotmat(rng.normal(size=3), 3.0).T
    raw2d = project(moved) + rng.normal(0, 0.5, (n_raw, 2))
    edge2d = project(edge_pts) + rng.normal(0, 0.3, (n_edge, 2))

    def path(kind: str, inl: int) -> PathMeasurement:
        return PathMeasurement(
            kind=kind, method=kind, evidence=Evidence.ABSOLUTE, n_kpts_render=500,
            n_kpts_photo=500, n_matches=2 * inl, n_inliers=inl, inlier_ratio=0.5, reason="",
            photo_from_render=tuple(map(tuple, np.eye(3))), corner_error_px=2.0)

    def frame(fid: str, with_edges: bool) -> FrameMeasurement:
        p2 = np.r_[raw2d, edge2d] if with_edges else raw2d
        pc = np.r_[raw_pts, edge_pts] if with_edges else raw_pts
        counts = (n_raw, n_edge) if with_edges else (n_raw,)
        ev = AbsoluteEvidence(("raw", "edges") if with_edges else ("raw",),
                              tuple(map(tuple, p2)), tuple(map(tuple, pc)), counts)
        return FrameMeasurement(
            frame_id=fid, timestamp=0, image_path=f"{fid}.png", width=w, height=h,
            center=(0.0, 0.0, 0.0), coverage=0.8, camera_id="cam0",
            world_from_cam=tuple(map(tuple, np.eye(4))),
            intrinsics=(f, f, (w - 1) / 2, (h - 1) / 2), raw=path("raw", n_raw),
            edges=path("edges", 900) if with_edges else None, evidence=ev, verdict_path="raw")

    cfg = RunConfig()
    cfg = replace(cfg, run_checks=replace(cfg.run_checks, enabled=False))
    both, raw_only = judge_run([frame("both", True), frame("raw", False)], cfg).frames
    # the feature points alone bound the frame beyond the threshold ...
    from pgt_check.verdict.frame_bounds import frame_bounds

    alone = frame_bounds([frame("both", True)])["both"]
    assert alone.evidence == "raw" and alone.accuracy.effect_bound_px > both.threshold_px
    # ... the PASS is stated and checked on every point it rests on, within the threshold
    assert both.verdict == "PASS", both.reason
    assert both.bound.evidence == "raw+edges"
    assert both.bound.accuracy.effect_bound_px <= both.threshold_px
    assert raw_only.verdict == "UNVERIFIABLE"
    assert raw_only.reason.startswith("bound_above_threshold")
