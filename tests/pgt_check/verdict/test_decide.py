import math

import numpy as np
import pytest

from pgt_check.config import GateConfig, VerdictConfig
from pgt_check.enhance.base import Evidence
from pgt_check.measure import FrameMeasurement, MeasureReason, PathMeasurement
from pgt_check.verdict import Verdict, decide, gate, resolve_threshold_px, systematic_offset
from pgt_check.verdict.run_stats import statistics_of_rows


def _m(error="", coverage=0.8, homography_reason="", n_inliers=100, inlier_ratio=0.5,
       corner_error_px=2.0):
    """A measurement whose raw path decides, with the given fields."""
    ok = not homography_reason
    path = PathMeasurement(
        kind="raw", method="render", evidence=Evidence.ABSOLUTE, n_kpts_render=500,
        n_kpts_photo=500, n_matches=200, n_inliers=n_inliers, inlier_ratio=inlier_ratio,
        reason=homography_reason, photo_from_render=tuple(map(tuple, np.eye(3))) if ok else None,
        corner_error_px=corner_error_px if ok else None,
    )
    return FrameMeasurement(
        frame_id="f", timestamp=0, image_path="f.png", width=640, height=480,
        center=(0.0, 0.0, 0.0), error=MeasureReason(error), coverage=coverage, raw=path,
        verdict_path="raw",
    )


def test_threshold_defaults_to_fraction_of_diagonal():
    assert resolve_threshold_px(VerdictConfig(), 640, 480) == pytest.approx(16.0)
    assert resolve_threshold_px(VerdictConfig(threshold_px=7.5), 640, 480) == 7.5


@pytest.mark.parametrize(
    "kw,verdict,reason",
    [
        ({}, Verdict.PASS, ""),
        ({"corner_error_px": 20.0}, Verdict.FAIL, "corner_error 20.0 px > 16.0 px"),
        ({"error": "image_missing"}, Verdict.UNVERIFIABLE, "image_missing"),
        ({"coverage": 0.01}, Verdict.UNVERIFIABLE, "low_coverage"),
        ({"homography_reason": "orientation_flip"}, Verdict.UNVERIFIABLE, "orientation_flip"),
        ({"n_inliers": 3}, Verdict.UNVERIFIABLE, "too_few_inliers"),
        ({"corner_error_px": math.inf}, Verdict.UNVERIFIABLE, "non_finite_homography"),
        ({"corner_error_px": None}, Verdict.UNVERIFIABLE, "non_finite_homography"),
    ],
)
def test_decide(kw, verdict, reason):
    assert decide(_m(**kw), VerdictConfig()) == (verdict, reason)


def test_threshold_boundary_is_inclusive():
    assert decide(_m(corner_error_px=16.0), VerdictConfig())[0] == Verdict.PASS


def test_gate():
    cfg = GateConfig(max_fail_fraction=0.1)
    assert gate({"PASS": 9, "FAIL": 1, "UNVERIFIABLE": 0}, cfg)[0]
    assert not gate({"PASS": 8, "FAIL": 2, "UNVERIFIABLE": 0}, cfg)[0]
    assert not gate({}, cfg)[0]
    assert not gate({"PASS": 5, "UNVERIFIABLE": 5}, GateConfig(max_unverifiable_fraction=0.2))[0]


def test_systematic_offset_detected_for_consistent_shift():
    shifts = [(-8.0 + 0.5 * (i % 2), -2.0) for i in range(20)]
    out = systematic_offset(shifts, [1.0] * 20, threshold_px=16.0)
    assert out.systematic and out.consistency == 1.0
    assert out.median_dx_px == pytest.approx(-8.0, abs=0.5)
    assert "calibration" in out.message


def test_random_shifts_are_not_systematic():
    import numpy as np

    rng = np.random.default_rng(0)
    ang = rng.uniform(0, 2 * np.pi, 40)
    shifts = list(zip(8 * np.cos(ang), 8 * np.sin(ang), strict=False))
    out = systematic_offset(shifts, [1.0] * 40, threshold_px=16.0)
    assert not out.systematic


def test_zoom_is_systematic():
    out = systematic_offset([(0.1, 0.0)] * 10, [0.89] * 10, threshold_px=16.0)
    assert out.systematic and "scaled by 0.890" in out.message


def test_run_statistics_counts_and_auc():
    recs = [
        {"verdict": "PASS", "reason": "", "corner_error_px": 0.5, "shift_dx_px": 0.1, "shift_dy_px": 0, "zoom": 1},
        {"verdict": "FAIL", "reason": "x", "corner_error_px": 30.0, "shift_dx_px": 30, "shift_dy_px": 0, "zoom": 1},
        {"verdict": "UNVERIFIABLE", "reason": "low_coverage", "corner_error_px": None},
    ]
    s = statistics_of_rows(recs, 16.0).to_json()
    assert s["counts"] == {"PASS": 1, "FAIL": 1, "UNVERIFIABLE": 1}
    assert s["unverifiable_reasons"] == {"low_coverage": 1}
    assert s["corner_error_px"]["n_measured"] == 2
    assert s["auc"]["auc@1px"] == pytest.approx((1 / 3) * 0.5 + (1 / 3) * 0.5 * 0.5 / 1 * 1, rel=0.5)
    assert 0 < s["auc"]["auc@1px"] < 1 / 3 + 1e-9


def test_systematic_offset_uses_the_raw_path_when_measured():
    """Enhanced renders borrow appearance from a neighbour with the same calibration, so their
    shift is ~0 even when every raw render is off by the same 9 px."""
    recs = [
        {"verdict": "PASS", "reason": "", "corner_error_px": 1.0, "shift_dx_px": 0.5,
         "shift_dy_px": 0.0, "zoom": 1.0, "shift_dx_px_raw": -9.0, "shift_dy_px_raw": -2.0,
         "zoom_raw": 1.0}
        for _ in range(10)
    ]
    s = statistics_of_rows(recs, 20.0).to_json()["systematic_offset"]
    assert s["path"] == "raw" and s["systematic"]
    assert s["median_dx_px"] == pytest.approx(-9.0)


def _path(kind, err, inliers=120, reference_id=None, evidence=Evidence.ABSOLUTE):
    ok = err is not None
    return PathMeasurement(
        kind=kind, method="render" if kind != "enhanced" else "reproject", evidence=evidence,
        n_kpts_render=500, n_kpts_photo=500, n_matches=200, n_inliers=inliers if ok else 5,
        inlier_ratio=0.5 if ok else 0.02, reason="" if ok else "too_few_inliers",
        photo_from_render=tuple(map(tuple, np.eye(3))) if ok else None,
        corner_error_px=err, reference_id=reference_id,
    )


def _frame(fid, raw_err, enh_err=None, ref=None):
    """Raw path with ``raw_err`` (None: too few inliers); an enhanced relative path through
    reference ``ref`` with ``enh_err`` (None: not run); the enhanced path decides if it ran."""
    enh = None if enh_err is None else _path("enhanced", enh_err, 150, ref, Evidence.RELATIVE)
    return FrameMeasurement(
        frame_id=fid, timestamp=0, image_path=f"{fid}.png", width=640, height=480,
        center=(0.0, 0.0, 0.0), coverage=0.8, raw=_path("raw", raw_err, 60), enhanced=enh,
        verdict_path="enhanced" if enh is not None else "raw",
    )


@pytest.mark.parametrize(
    ("raw_err", "verdict", "reason"),
    [
        (3.0, "PASS", ""),  # this frame's own render passes clearly
        (None, "UNVERIFIABLE", "reference_off"),  # nothing absolute to judge it by
        (12.0, "PASS", ""),  # passes, not clearly: still its own absolute evidence
        (40.0, "FAIL", "corner_error"),  # its own render fails too
    ],
)
def test_a_reference_that_fails_on_its_own_render_does_not_decide(raw_err, verdict, reason):
    """Frame g reprojects reference b; b's own render is 50 px off, so the reprojection
    paints b's error into g's view: a confident relative FAIL of g is not g's own."""
    from pgt_check.config import VerdictConfig
    from pgt_check.verdict.decide import judge, own_outcomes

    cfg = VerdictConfig()
    bad_ref = _frame("b", 50.0)
    g = _frame("g", raw_err, enh_err=45.0, ref="b")
    own = own_outcomes([bad_ref, g], cfg)
    assert own["b"] is True
    j = judge(g, cfg, None, own)
    assert j.verdict.value == verdict
    assert j.reason.startswith(reason)
    assert j.decided_by == ("enhanced" if reason == "reference_off" else "raw")
    # without knowing the reference's own result the confident relative FAIL stands
    assert judge(g, cfg, None, None).verdict is Verdict.FAIL
    # a good reference: the relative FAIL is this frame's
    good_ref = _frame("b", 2.0)
    assert judge(g, cfg, None, own_outcomes([good_ref, g], cfg)).verdict is Verdict.FAIL
    # a reference just above the threshold (16 px here) is not clearly off: it still serves
    near_ref = _frame("b", 20.0)
    assert own_outcomes([near_ref], cfg)["b"] is False
    assert judge(g, cfg, None, own_outcomes([near_ref, g], cfg)).verdict is Verdict.FAIL


@pytest.mark.parametrize(
    ("edge_err", "verdict", "reason", "decided_by"),
    [(4.8, "PASS", "", "edges"), (12.0, "UNVERIFIABLE", "paths_disagree", "raw")],
)
def test_a_weak_raw_fail_against_an_edge_pass(edge_err, verdict, reason, decided_by):
    """Raw render with 18 inliers just over the threshold (16 px): a clear PASS of the
    geometric-edge path (within half the threshold) decides; a PASS near the threshold leaves
    the two absolute paths disagreeing. A confident raw FAIL stands either way."""
    from pgt_check.verdict.decide import judge

    cfg = VerdictConfig()
    m = _frame("w", 17.0)
    m = FrameMeasurement(**{**m.__dict__, "raw": _path("raw", 17.0, 18),
                            "edges": _path("edges", edge_err, 2000)})
    j = judge(m, cfg)
    assert (j.verdict.value, j.decided_by) == (verdict, decided_by), j
    assert j.reason.startswith(reason)
    m40 = FrameMeasurement(**{**m.__dict__, "raw": _path("raw", 17.0, 40)})
    assert judge(m40, cfg).verdict is Verdict.FAIL


def test_a_relative_fail_does_not_outweigh_an_absolute_pass():
    """A reprojected reference's FAIL (relative evidence, few inliers) against the edge
    path's PASS near the threshold: the absolute PASS decides (on TSDF-fused scans the
    reprojection through the scan's rounded geometry failed correct frames). A confident
    relative FAIL still stands, and so does the UNVERIFIABLE of two absolute paths that
    disagree (test above)."""
    from pgt_check.verdict.decide import judge

    cfg = VerdictConfig()
    m = _with(_frame("r", None), enhanced=_path("enhanced", 25.0, 20, "q", Evidence.RELATIVE),
              edges=_path("edges", 12.0, 2000), verdict_path="enhanced")
    j = judge(m, cfg)
    assert (j.verdict, j.decided_by, j.evidence) == (Verdict.PASS, "edges", "absolute"), j
    confident = _with(m, enhanced=_path("enhanced", 25.0, 150, "q", Evidence.RELATIVE))
    assert judge(confident, cfg).verdict is Verdict.FAIL
    far = _with(m, edges=_path("edges", 20.0, 2000))  # the edge path fails too
    assert judge(far, cfg).verdict is Verdict.FAIL


def _with(m, **kw):
    return FrameMeasurement(**{**m.__dict__, **kw})


@pytest.mark.parametrize(("alt_inliers", "verdict", "reference"), [(60, "PASS", "p"), (30, "FAIL", "b")])
def test_a_reference_the_run_does_not_pass_gives_way_to_one_it_does(alt_inliers, verdict, reference):
    """Neighbours err together: good frame g was reprojected through its bad neighbour b (45 px,
    the most inliers) and through p, which passes on its own render (3 px). b fails in the
    first pass, so g is judged through p: its edges confirm, PASS. A weak result through p
    (fewer than ``confident_inliers``) does not take over: the confident FAIL through b
    stands. b itself (judged through g, which also failed first) stays FAIL."""
    from pgt_check.config import RunConfig
    from pgt_check.verdict import judge_run

    p = _frame("p", 2.0)
    b = _frame("b", None, enh_err=45.0, ref="g")
    g = _with(
        _frame("g", None, enh_err=45.0, ref="b"),
        edges=_path("edges", 3.0, 2000),
        enhanced_alternatives=(
            _path("enhanced", 3.0, alt_inliers, "p", Evidence.RELATIVE),
        ),
    )
    rows = {r["frame_id"]: r for r in judge_run([p, b, g], RunConfig.from_dict(
        {"run_checks": {"enabled": False}})).rows()}
    assert rows["p"]["verdict"] == "PASS"
    assert rows["b"]["verdict"] == "FAIL"
    assert (rows["g"]["verdict"], rows["g"]["reference_id"]) == (verdict, reference)
    if verdict == "PASS":
        assert rows["g"]["corner_error_px_enhanced"] == pytest.approx(3.0)
        assert rows["g"]["evidence"] == "absolute"  # the edge path confirms the relative PASS



def test_a_reference_that_passed_only_through_its_own_references_vouches_for_nothing():
    """7-Scenes, 40 % wrong: a correct frame FAILed at 44 px through a neighbour whose PASS
    rested on that neighbour's own references (relative evidence confirmed by the
    registration), and measured 14 px through a frame that passed on its own render. Only a
    reference the run passes on its own absolute evidence vouches: q (PASS through its
    references) does not, so g is judged through p."""
    from pgt_check.verdict.decide import judge
    from pgt_check.verdict.judgement import Judgement
    from pgt_check.verdict.vouching import vouched_frames, vouched_reference

    cfg = VerdictConfig()
    p, q = _frame("p", 2.0), _frame("q", None, enh_err=3.0, ref="p")
    passed = {
        "p": Judgement(Verdict.PASS, "", "absolute", "PASS", "", decided_by="raw"),
        "q": Judgement(Verdict.PASS, "", "relative+registration", "", "PASS",
                       decided_by="enhanced"),
    }
    assert vouched_frames([p, q], [passed["p"], passed["q"]]) == {"p"}
    g = _with(
        _frame("g", None, enh_err=45.0, ref="q"),
        edges=_path("edges", 3.0, 2000),
        enhanced_alternatives=(_path("enhanced", 3.0, 60, "p", Evidence.RELATIVE),),
    )
    first = judge(g, cfg)
    assert first.verdict is Verdict.FAIL and first.decided_by == "enhanced"
    g2 = vouched_reference(g, first, {"p"}, cfg)
    assert g2 is not None and g2.enhanced is not None and g2.enhanced.reference_id == "p"
    assert judge(g2, cfg).verdict is Verdict.PASS
    # q vouched for (its PASS counted whatever its evidence): nothing changes
    assert vouched_reference(g, first, {"p", "q"}, cfg) is None
