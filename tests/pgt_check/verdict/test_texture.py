"""Mesh colours against mesh geometry (``shared_errors.texture``): a mesh coloured with the
checked poses carries their shared error in its colours; texture matches and geometric edges
then place the photos differently in every frame alike."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from pgt_check.config import RunConfig
from pgt_check.geometry.shared_errors.texture import FramePoints, texture_offset
from pgt_check.measure import AbsoluteEvidence, FrameMeasurement
from pgt_check.report.headline import shared_error_lines
from pgt_check.verdict import judge_run

F, CX, CY = 500.0, 319.5, 239.5
K = np.array([[F, 0, CX], [0, F, CY], [0, 0, 1.0]])


def _points(rng, n: int, shift=(0.0, 0.0), noise: float = 0.7):
    """(pts2d, pts_cam): random points 2-5 m ahead, observed ``shift`` px off their projection."""
    cam = np.c_[rng.uniform(-1, 1, (n, 2)) * 1.5, rng.uniform(2, 5, n)]
    uv = cam[:, :2] / cam[:, 2:] * F + [CX, CY]
    return uv + np.asarray(shift) + rng.normal(0, noise, (n, 2)), cam


def _frames(n_frames: int, shift, seed: int = 0, n_tex: int = 20, n_geo: int = 80):
    rng = np.random.default_rng(seed)
    return [
        FramePoints(K, *_points(rng, n_tex, shift), *_points(rng, n_geo))
        for _ in range(n_frames)
    ]


def test_offset_is_recovered_with_an_interval():
    est = texture_offset(_frames(12, (6.0, 3.0)))
    assert est.success and est.n_frames == 12
    assert est.offset_px == pytest.approx((6.0, 3.0), abs=0.6)
    lo, hi = est.effect_px_ci
    assert lo < est.effect_px < hi and lo > 5.0


def test_no_offset_and_too_few_frames():
    est = texture_offset(_frames(12, (0.0, 0.0)))
    assert est.success and est.effect_px_ci[1] < 1.0
    assert texture_offset(_frames(4, (6.0, 3.0))).reason == "too_few_frames"
    # frames with too few texture points do not count
    assert not texture_offset(_frames(12, (6.0, 3.0), n_tex=3)).success


def test_outlier_frames_do_not_move_the_median():
    frames = _frames(12, (6.0, 3.0))
    frames[:3] = _frames(3, (-40.0, 25.0), seed=1)  # frames with an error of their own
    assert texture_offset(frames).offset_px == pytest.approx((6.0, 3.0), abs=1.5)


def _measurements(shift, shading: str = "vertex", n_frames: int = 10) -> list[FrameMeasurement]:
    rng = np.random.default_rng(3)
    out = []
    for i in range(n_frames):
        t2, t3 = _points(rng, 20, shift)
        g2, g3 = _points(rng, 80)
        pose = np.eye(4)
        pose[0, 3] = 0.3 * i
        out.append(FrameMeasurement(
            frame_id=f"f{i}", timestamp=float(i), image_path=None, width=640, height=480,
            center=tuple(pose[:3, 3]), coverage=0.9, shading=shading,
            world_from_cam=tuple(map(tuple, pose)),
            intrinsics=(F, F, CX, CY), camera_id="cam0",
            evidence=AbsoluteEvidence(
                ("raw", "edges"),
                tuple(map(tuple, np.r_[t2, g2])),
                tuple(map(tuple, np.r_[t3, g3])),
                (20, 80),
            ),
        ))  # fmt: skip
    return out


def test_run_summary_states_the_finding():
    se = judge_run(_measurements((6.0, 3.0)), RunConfig()).shared.summary()
    tex = se["texture"]
    assert tex["status"] == "finding", tex
    assert tex["offset_px"] == pytest.approx([6.0, 3.0], abs=0.6)
    assert "coloured with these poses" in tex["message"]
    assert tex["message"] in shared_error_lines(se)  # the CLI prints it


def test_agreeing_colours_pass_and_colourless_renders_are_not_checked():
    se = judge_run(_measurements((0.0, 0.0)), RunConfig()).shared.summary()
    assert se["texture"]["status"] == "passed"
    assert se["texture"]["message"] not in shared_error_lines(se)
    # a shaded render's matches see geometry, not colours: nothing to compare
    shaded = judge_run(_measurements((6.0, 3.0), shading="shaded"), RunConfig())
    assert "texture" not in shaded.shared.summary()


def test_evidence_counts_split_the_points_and_round_trip():
    m = _measurements((6.0, 3.0), n_frames=1)[0]
    parts = m.evidence.by_source()
    assert [len(parts[s][0]) for s in ("raw", "edges")] == [20, 80]
    assert AbsoluteEvidence.from_json(m.evidence.to_json()) == m.evidence
    old = AbsoluteEvidence.from_json({**m.evidence.to_json(), "counts": []})
    assert old.by_source() == {}  # records written before the counts: split unknown
    with pytest.raises(ValueError, match="counts"):
        dataclasses.replace(m.evidence, counts=(20, 79))


def test_texture_matches_without_geometry_say_the_check_could_not_run():
    """Decisive texture matches and no edge evidence (e.g. XFeat on a coloured mesh): a shared
    error painted into the colours would go unseen; the entry and the CLI say so."""
    raw_only = [
        dataclasses.replace(m, evidence=AbsoluteEvidence(
            ("raw",), m.evidence.pts2d[:20], m.evidence.pts_cam[:20], (20,)))
        for m in _measurements((6.0, 3.0))
    ]  # fmt: skip
    se = judge_run(raw_only, RunConfig()).shared.summary()
    tex = se["texture"]
    assert tex["status"] == "not_checked" and tex["reason"] == "no_geometric_evidence"
    assert "--edges always" in tex["message"] and "10 frames" in tex["message"]
    assert tex["message"] in shared_error_lines(se)
