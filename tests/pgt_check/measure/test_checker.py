"""Unit tests of ``pgt_check.measure.checker`` (``FrameChecker``, ``build_frame_checker``) on the
generated sample scene (``sample_data/scene``: 320x240 photos of a textured mesh) and frames
moved with ``pgt_eval.perturb_pose``. The golden frames.csv beside them (test_equivalence.py)
pins whole runs; these pin what one frame's measurement does with each path and failure."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

import pgt_check.measure.checker as checker_module
import pgt_check.measure.edge_path as edge_path_module
from pgt_check.config import RunConfig
from pgt_check.io import read_trajectory
from pgt_check.measure import (
    EnhanceWhy,
    FrameChecker,
    MeasureReason,
    build_frame_checker,
    pick_references,
)
from pgt_check.verdict import apply_verdicts
from pgt_eval import perturb_pose

#: raw path only: no enhancement, no geometric edges (fast, and each test turns on what it needs)
RAW_ONLY = {"enhance": {"mode": "never"}, "edges": {"mode": "never"}}


@pytest.fixture(scope="module")
def traj(sample_scene):
    return read_trajectory(sample_scene / "trajectories.txt")


@pytest.fixture(scope="module")
def mesh(sample_scene):
    return str(sample_scene / "mesh.glb")


def _config(mesh: str, **sections) -> RunConfig:
    return RunConfig.from_dict({"input": {"mesh": mesh}, **sections})


def _measure(cfg: RunConfig, frames, references=None, **kwargs):
    checker = FrameChecker(cfg, references or {}, **kwargs)
    try:
        return [checker.measure(f) for f in frames]
    finally:
        checker.close()


def _moved(frame, rotation_deg: float, translation: float = 0.0, seed: int = 0):
    pose = perturb_pose(
        frame.world_from_cam, rotation_deg, translation, np.random.default_rng(seed)
    )
    return frame.with_pose(pose)


def test_a_perturbed_pose_gets_a_larger_corner_error_than_the_true_pose(traj, mesh):
    f = traj.frames[0]
    true, rot, shift = _measure(
        _config(mesh, **RAW_ONLY), [f, _moved(f, 3.0), _moved(f, 0.0, 0.15, seed=1)]
    )
    for m in (true, rot, shift):
        assert m.error is MeasureReason.NONE, m.error_detail
        assert m.raw is not None and m.raw.success
        assert m.verdict_path == "raw"
    assert true.raw.corner_error_px < 2.0  # the photo was rendered at this pose
    assert rot.raw.corner_error_px > 4 * true.raw.corner_error_px
    assert rot.raw.corner_error_px > 5.0
    assert shift.raw.corner_error_px > 4 * true.raw.corner_error_px
    # the frame's own size and the working size (320 px fits the default 640 matching size)
    assert (true.width, true.height, true.match_width, true.match_height) == (320, 240, 320, 240)
    assert true.coverage > 0.5
    # PnP on the matched render depth: the true pose needs almost no correction, 3 deg does
    assert true.pose is not None and true.pose.drot_deg < 0.5
    assert rot.pose is not None and 2.0 < rot.pose.drot_deg < 4.0
    assert true.timings.total > 0 and true.timings.render > 0 and true.timings.match > 0


def test_a_frame_pointed_away_from_the_mesh_is_low_coverage_without_matching(traj, mesh):
    f = traj.frames[0]
    away = f.world_from_cam.copy()
    away[2, 3] += 50.0  # the camera 50 units above the scene, looking past it
    checker = FrameChecker(_config(mesh, **RAW_ONLY), {})
    try:
        m = checker.measure(f.with_pose(away))
        assert checker._matcher is None  # the matcher was never built: nothing was matched
    finally:
        checker.close()
    assert m.error is MeasureReason.LOW_COVERAGE
    assert m.coverage < 0.05
    assert m.raw is None and m.pose is None


def test_a_missing_image_is_a_reason_not_an_exception(traj, mesh, tmp_path):
    f = dataclasses.replace(traj.frames[0], image_file=tmp_path / "gone.png")
    (m,) = _measure(_config(mesh, **RAW_ONLY), [f])
    assert m.error is MeasureReason.IMAGE_MISSING
    assert m.raw is None


def test_an_unreadable_image_is_image_unreadable(traj, mesh, tmp_path):
    bad = tmp_path / "broken.png"
    bad.write_bytes(b"not a png")
    f = dataclasses.replace(traj.frames[0], image_file=bad)
    (m,) = _measure(_config(mesh, **RAW_ONLY), [f])
    assert m.error is MeasureReason.IMAGE_UNREADABLE
    assert m.error_detail


class _BrokenRenderer:
    def render(self, camera, world_from_cam):
        raise RuntimeError("GL context lost")

    def close(self):
        pass


def test_a_failed_render_becomes_an_unverifiable_frame_with_a_reason(traj, mesh):
    cfg = _config(mesh, **RAW_ONLY)
    checker = FrameChecker(cfg, {})
    checker._renderer = _BrokenRenderer()
    m = checker.measure(traj.frames[0])  # no exception
    assert m.error is MeasureReason.INTERNAL_ERROR
    assert "RuntimeError: GL context lost" in m.error_detail  # the traceback is kept
    assert m.timings.total > 0
    (row,) = apply_verdicts([m], cfg)
    assert row["verdict"] == "UNVERIFIABLE"
    assert "internal_error" in row["reason"]


def test_fail_fast_reraises_a_failed_render(traj, mesh):
    checker = FrameChecker(_config(mesh, fail_fast=True, **RAW_ONLY), {})
    checker._renderer = _BrokenRenderer()
    with pytest.raises(RuntimeError, match="GL context lost"):
        checker.measure(traj.frames[0])


def test_paths_that_are_off_are_not_computed(traj, mesh, monkeypatch):
    calls = []
    real = edge_path_module.measure_edges
    monkeypatch.setattr(
        edge_path_module, "measure_edges", lambda *a: calls.append("edges") or real(*a)
    )
    cfg = _config(mesh, pose={"enabled": False}, **RAW_ONLY)
    checker = FrameChecker(cfg, pick_references(traj, traj.frames[:1], cfg))
    try:
        (m,) = [checker.measure(traj.frames[0])]
        assert checker._enhancer is None  # never built
    finally:
        checker.close()
    assert calls == []
    assert m.edges is None
    assert m.enhanced is None and not m.enhance_ran
    assert m.enhance_why is EnhanceWhy.MODE_NEVER
    assert m.pose is None
    assert m.raw is not None and m.raw.success
    assert m.evidence is not None and m.evidence.sources == ("raw",)


def test_edges_always_adds_the_edge_path_and_its_evidence(traj, mesh, monkeypatch):
    calls = []
    real = edge_path_module.measure_edges
    monkeypatch.setattr(
        edge_path_module, "measure_edges", lambda *a: calls.append("edges") or real(*a)
    )
    (m,) = _measure(
        _config(mesh, enhance={"mode": "never"}, edges={"mode": "always"}), traj.frames[:1]
    )
    assert calls == ["edges"]
    assert m.edges is not None and m.edges.kind == "edges"
    assert m.verdict_path == "raw"  # the raw path aligned: it decides
    assert m.evidence is not None and "edges" in m.evidence.sources


def test_edges_auto_is_left_out_where_the_raw_path_is_decisive(traj, mesh, monkeypatch):
    calls = []
    monkeypatch.setattr(edge_path_module, "measure_edges", lambda *a: calls.append(a))
    (m,) = _measure(
        _config(mesh, enhance={"mode": "never"}, edges={"mode": "auto"}), traj.frames[:1]
    )
    assert m.raw.n_inliers >= 40 and m.raw.corner_error_px < 1.0  # decisive raw PASS
    assert calls == [] and m.edges is None


@pytest.mark.parametrize(
    "raw_ratio, raw_inliers, enhanced",
    [
        (0.7, 60, True),  # raw aligned near the threshold: it contradicts the edges' clear PASS
        (1.6, 25, True),  # raw FAILs on a few inliers: the enhanced path breaks the tie
        (0.2, 25, False),  # raw agrees (a low error on few inliers): the edges decide
    ],
)
def test_a_clear_edge_pass_leaves_out_the_enhancement_only_where_the_raw_path_agrees(
    traj, mesh, monkeypatch, raw_ratio, raw_inliers, enhanced
):
    """Two absolute paths that disagree (the raw render aligned but not within the clear band,
    the edges clearly PASS) get the enhanced path as a third witness."""
    cfg = _config(mesh, enhance={"mode": "auto", "method": "reproject"}, edges={"mode": "auto"})
    frame = traj.frames[4]
    thr = cfg.verdict.threshold_for(frame.camera.width, frame.camera.height)
    real = checker_module.match_path

    def raw_path(*a, **k):
        r = real(*a, **k)
        assert r.success  # the sample scene's raw render aligns
        return dataclasses.replace(r, corner_error_px=raw_ratio * thr, n_inliers=raw_inliers)

    monkeypatch.setattr(checker_module, "match_path", raw_path)
    monkeypatch.setattr(checker_module, "edges_decisive", lambda *a: True)
    (m,) = _measure(cfg, [frame], pick_references(traj, [frame], cfg))
    assert m.edges is not None  # the raw path is not decisive: the edges ran
    if enhanced:
        assert m.enhance_why is not EnhanceWhy.EDGES_DECISIVE
        assert m.enhanced is not None and m.enhance_ran
    else:
        assert m.enhance_why is EnhanceWhy.EDGES_DECISIVE
        assert m.enhanced is None and not m.enhance_ran


def test_edges_lead_on_a_shaded_render_and_a_clear_pass_leaves_out_the_raw_path(traj, mesh):
    cfg = _config(mesh, render={"shading": "shaded"}, enhance={"mode": "never"})
    (m,) = _measure(cfg, traj.frames[:1])
    assert m.shading == "shaded"
    assert m.edges is not None and m.edges.success
    assert m.raw is None and m.enhanced is None
    assert m.enhance_why is EnhanceWhy.EDGES_DECISIVE
    assert m.enhance_why_detail == "raw_left_out"
    assert m.verdict_path == "edges"
    # with the lead off the raw path runs (and matches the shading, or fails to)
    (plain,) = _measure(
        _config(
            mesh,
            render={"shading": "shaded"},
            enhance={"mode": "never"},
            edges={"lead_on_shaded": False},
        ),
        traj.frames[:1],
    )
    assert plain.raw is not None


def test_enhance_always_matches_the_reprojected_reference(traj, mesh):
    cfg = _config(mesh, enhance={"mode": "always", "method": "reproject"}, edges={"mode": "never"})
    frame = _moved(traj.frames[4], 3.0)
    refs = pick_references(traj, [frame], cfg)
    assert refs[frame.frame_id]  # the neighbours serve as references
    (m,) = _measure(cfg, [frame], refs)
    assert m.enhance_ran and m.enhance_why is EnhanceWhy.MODE_ALWAYS
    assert m.enhanced is not None and m.enhanced.kind == "enhanced"
    assert m.enhanced.method == "reproject"
    assert m.enhanced.reference_id in {r.frame_id for r in refs[frame.frame_id]}
    assert m.verdict_path in ("raw", "enhanced")


def test_enhance_without_references_says_so(traj, mesh):
    cfg = _config(mesh, enhance={"mode": "always", "method": "reproject"}, edges={"mode": "never"})
    (m,) = _measure(cfg, traj.frames[:1], references={})
    assert m.enhanced is None
    assert m.enhance_why is EnhanceWhy.NO_REFERENCE and not m.enhance_ran


def test_an_unreadable_reference_is_reference_unreadable(traj, mesh, tmp_path):
    bad = tmp_path / "ref.png"
    bad.write_bytes(b"broken")
    ref = dataclasses.replace(traj.frames[1], image_file=bad)
    cfg = _config(mesh, enhance={"mode": "always", "method": "reproject"}, edges={"mode": "never"})
    f = traj.frames[0]
    (m,) = _measure(cfg, [f], references={f.frame_id: (ref,)})
    assert m.error is MeasureReason.REFERENCE_UNREADABLE
    assert "ref" in m.error_detail


def test_panel_sink_sees_the_images_and_its_failure_does_not_stop_the_frame(traj, mesh):
    seen = []

    def sink(m, images):
        seen.append(
            (m.frame_id, images.photo.shape, images.render.shape, int(images.inliers.sum()))
        )
        raise OSError("disk full")

    (m,) = _measure(_config(mesh, **RAW_ONLY), traj.frames[:1], panel_sink=sink)
    assert m.error is MeasureReason.NONE and m.raw.success
    assert seen == [(m.frame_id, (240, 320, 3), (240, 320, 3), m.raw.n_inliers)]


def test_keep_collects_the_images_without_changing_the_measurement(traj, mesh):
    from pgt_check.measure import FrameImages

    cfg = _config(mesh, **RAW_ONLY)
    checker = FrameChecker(cfg, {})
    try:
        plain = checker.measure(traj.frames[0])
        keep = FrameImages()
        kept = checker.measure(traj.frames[0], keep=keep)
    finally:
        checker.close()
    assert keep.photo is not None and keep.render is not None and "raw" in keep.paths
    assert kept.raw == plain.raw and kept.evidence == plain.evidence


def test_build_frame_checker_loads_its_resources_up_front(mesh):
    checker = build_frame_checker(_config(mesh, **RAW_ONLY))
    try:
        assert checker._renderer is not None and checker._matcher is not None
        assert checker._enhancer is None  # built on first use only
        assert checker.references == {}
    finally:
        checker.close()
    assert checker._renderer is None  # close releases the renderer


def test_pick_references_is_empty_when_the_enhancement_is_off(traj, mesh):
    assert pick_references(traj, traj.frames, _config(mesh, **RAW_ONLY)) == {}


def test_references_are_tried_until_one_gives_a_clear_pass(traj, mesh):
    """Issue #28: the second reference is left out where the first already gives a clear PASS,
    and tried where the first reference's own pose is off (its texture lands elsewhere)."""
    cfg = _config(mesh, enhance={"mode": "always", "method": "reproject"}, edges={"mode": "never"})
    frame = traj.frames[6]  # frames 3 and 7 of the sample scene are perturbed: not used here
    good = (traj.frames[5], traj.frames[4])
    bad_first = (_moved(traj.frames[5], 4.0, seed=2), traj.frames[4])
    seen = []
    checker = FrameChecker(cfg, {})
    enhance = checker.enhancer.enhance

    def counting(view, reference, renderer):
        seen.append(reference.frame_id)
        return enhance(view, reference, renderer)

    checker.enhancer.enhance = counting
    try:
        checker.references = {frame.frame_id: good}
        m = checker.measure(frame)
        assert seen == [good[0].frame_id]  # a clear PASS: the second is left out
        assert m.enhanced.reference_id == good[0].frame_id and not m.enhanced_alternatives
        assert m.enhanced.n_inliers >= cfg.enhance.auto_min_inliers
        seen.clear()
        checker.references = {frame.frame_id: bad_first}
        m = checker.measure(frame)
        assert seen == [f.frame_id for f in bad_first]  # not clear: the second is tried
        assert m.enhanced.reference_id == bad_first[1].frame_id
    finally:
        checker.close()
