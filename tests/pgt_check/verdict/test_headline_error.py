"""The headline error of a frame (``corner_error_px`` and the other headline columns in
frames.csv, the summary's median, the report table, JUnit) is the error of the path its verdict
rests on (``decided_by``), as the verdict compared it; a PASS never shows an error above its
threshold (issue #38 item 3)."""

from __future__ import annotations

import numpy as np
import pytest

from pgt_check.config import RunConfig, VerdictConfig
from pgt_check.enhance.base import Evidence
from pgt_check.measure import FrameMeasurement, PathMeasurement
from pgt_check.measure.columns import HEADLINE_COLUMNS
from pgt_check.report.junit import junit_xml_text
from pgt_check.verdict import judge_run
from pgt_check.verdict.run_stats import run_statistics


def _path(kind, err, inliers, evidence=Evidence.ABSOLUTE, ref=None, matches=None):
    ok = err is not None
    return PathMeasurement(
        kind=kind, method="render" if kind == "raw" else kind, evidence=evidence,
        n_kpts_render=500 + inliers, n_kpts_photo=400 + inliers,
        n_matches=matches or 2 * inliers, n_inliers=inliers if ok else 5,
        inlier_ratio=0.5 if ok else 0.02, reason="" if ok else "too_few_inliers",
        photo_from_render=tuple(map(tuple, np.eye(3))) if ok else None,
        corner_error_px=err, reference_id=ref,
    )


def _frame(fid, raw=None, enhanced=None, edges=None, verdict_path="raw"):
    return FrameMeasurement(
        frame_id=fid, timestamp=0, image_path=f"{fid}.png", width=640, height=480,
        center=(0.0, 0.0, 0.0), coverage=0.8, raw=raw, enhanced=enhanced, edges=edges,
        verdict_path=verdict_path,
    )


def _no_run_checks() -> RunConfig:
    cfg = RunConfig()
    from dataclasses import replace

    return replace(cfg, run_checks=replace(cfg.run_checks, enabled=False))


def test_a_frame_decided_by_the_edge_path_shows_the_edge_paths_error():
    """The issue's case: the enhanced (MaRINeR, absolute) path has more inliers, so it is the
    measurement's ``verdict_path``, but a weak FAIL (30 px); the edge path passes clearly
    (5 px) and decides. Before, ``corner_error_px`` showed the enhanced path's 30 px on a PASS
    with a 16 px threshold."""
    m = _frame(
        "e", raw=_path("raw", None, 5),
        enhanced=_path("enhanced", 30.0, 25, Evidence.ABSOLUTE, matches=90),
        edges=_path("edges", 5.0, 2000, matches=3000), verdict_path="enhanced",
    )
    res = judge_run([m], _no_run_checks())
    f = res.frames[0]
    assert (f.verdict, f.judgement.decided_by) == ("PASS", "edges"), f.judgement
    row = res.rows()[0]
    assert row["corner_error_px"] == pytest.approx(5.0)
    assert row["corner_error_px"] <= row["threshold_px"]
    assert (row["n_inliers"], row["n_matches"]) == (2000, 3000)  # the edge path's
    assert row["n_kpts_render"] == 2500
    # the other paths keep their own columns
    assert row["corner_error_px_enhanced"] == pytest.approx(30.0)
    assert row["corner_error_px_edges"] == pytest.approx(5.0)
    assert row["verdict_path"] == "enhanced"  # the measurement's choice, unchanged
    # the JUnit text and the run's median use the same error
    xml = junit_xml_text(res.rows(), {"counts": {}, "gate": {}})
    assert "corner error 5.00 px (edges path)" in xml and "30.00" not in xml
    assert run_statistics(res, 16.0).corner_error_px.median == pytest.approx(5.0)


def _random_frames(n: int, seed: int) -> list[FrameMeasurement]:
    """Frames with every combination of paths that ran, inlier counts around the confident
    and minimum levels, errors on both sides of the threshold and relative or absolute
    enhanced evidence."""
    rng = np.random.default_rng(seed)
    errs = [None, 2.0, 7.0, 12.0, 15.9, 17.0, 24.0, 60.0]
    inl = [8, 18, 30, 45, 150]
    out = []
    for i in range(n):
        paths = {}
        for kind in ("raw", "enhanced", "edges"):
            if rng.random() < 0.25:
                continue
            ev = Evidence.RELATIVE if kind == "enhanced" and rng.random() < 0.5 else \
                Evidence.ABSOLUTE
            ref = f"f{(i + 1) % n}" if ev is Evidence.RELATIVE else None
            paths[kind] = _path(kind, errs[rng.integers(len(errs))],
                                int(inl[rng.integers(len(inl))]) * (40 if kind == "edges" else 1),
                                ev, ref)
        feats = [k for k in ("raw", "enhanced") if k in paths and not paths[k].reason]
        vp = max(feats, key=lambda k: paths[k].n_inliers) if feats else (
            "edges" if "edges" in paths else "raw")
        out.append(_frame(f"f{i}", verdict_path=vp, **paths))
    return out


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_no_pass_shows_an_error_above_its_threshold(seed):
    """Invariant over many frames with paths that disagree: every PASS row's headline error
    is within its threshold, and every frame with a deciding path shows that path's error."""
    ms = _random_frames(300, seed)
    res = judge_run(ms, _no_run_checks())
    rows = res.rows()
    verdicts = {r["verdict"] for r in rows}
    assert {"PASS", "FAIL", "UNVERIFIABLE"} <= verdicts  # the draw covers every outcome
    # the frames where another path than the measurement's choice decided are many
    switched = [r for r in rows if r["decided_by"] and r["decided_by"] != r["verdict_path"]]
    assert len(switched) > 20
    for r in rows:
        if r["verdict"] == "PASS":
            assert r["corner_error_px"] is not None
            assert r["corner_error_px"] <= r["threshold_px"], r
        if r["decided_by"]:
            assert r["corner_error_px"] == r[f"corner_error_px_{r['decided_by']}"], r
            if r["decided_by"] != "edges" and r[f"n_matches_{r['decided_by']}"] is not None:
                assert r["n_inliers"] == r[f"n_inliers_{r['decided_by']}"], r
    assert set(HEADLINE_COLUMNS) <= set(rows[0])


def test_a_pass_after_removing_the_calibration_shows_the_error_it_was_judged_by():
    """With the camera's calibration error removed the verdict compares the corrected error:
    the headline shows that one (the raw column keeps the measured error)."""
    from pgt_check.verdict.decide import judge

    class _Shared:
        removes_calibration = True
        registration_status = "not_checked"
        drift_flagged: dict = {}
        drift_px: dict = {}

        def calibration_homography(self, frame_id, camera_id):
            return np.array([[1.0, 0, 20.0], [0, 1.0, 0], [0, 0, 1.0]])  # 20 px shift

        def calibration_changed(self, camera_id):
            return None

    # measured: a 20 px shift (above 16 px), all of it the calibration's
    shift = tuple(map(tuple, np.array([[1.0, 0, 20.0], [0, 1.0, 0], [0, 0, 1.0]])))
    raw = PathMeasurement(
        kind="raw", method="render", evidence=Evidence.ABSOLUTE, n_kpts_render=500,
        n_kpts_photo=500, n_matches=200, n_inliers=100, inlier_ratio=0.5, reason="",
        photo_from_render=shift, corner_error_px=20.0,
    )
    m = _frame("c", raw=raw)
    cfg = VerdictConfig()
    j = judge(m, cfg, _Shared())
    assert j.verdict.value == "PASS" and j.error_px == pytest.approx(0.0, abs=1e-6)
    from pgt_check.verdict.result import FrameResult

    row = FrameResult(m, j, cfg.threshold_for(640, 480)).row()
    assert row["corner_error_px"] == pytest.approx(0.0, abs=1e-6)
    assert row["corner_error_px_raw"] == pytest.approx(20.0)


def test_every_combination_of_headline_paths_reads_the_named_path():
    from pgt_check.measure.columns import headline_values

    paths = {k: _path(k, e, i) for k, e, i in
             (("raw", 3.0, 40), ("enhanced", 9.0, 70), ("edges", 1.0, 900))}
    m = _frame("x", **paths)
    for name in ("raw", "enhanced", "edges"):
        v = headline_values(m, name)
        assert v["corner_error_px"] == paths[name].corner_error_px
        assert v["n_inliers"] == paths[name].n_inliers
    with pytest.raises(ValueError):
        headline_values(m, "chosen")
