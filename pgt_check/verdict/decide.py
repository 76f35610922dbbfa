"""Stage 2: thresholds applied to stored measurements. Never re-renders or re-matches."""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from typing import TYPE_CHECKING, Any, NamedTuple

import numpy as np

from pgt_check.config import VerdictConfig
from pgt_check.constants import CLEAR_MARGIN
from pgt_check.enhance.base import Evidence
from pgt_check.measure.record import FrameMeasurement, MeasureReason, PathMeasurement
from pgt_check.verdict.judgement import CANNOT_SEPARATE, Judgement, PathOutcome, Verdict
from pgt_check.verdict.status import FAILED, NOT_CHECKED, PASSED

if TYPE_CHECKING:  # pragma: no cover
    from pgt_check.verdict.shared import SharedChecks

class Decision(NamedTuple):
    """A frame's judgement while ``judge`` applies its rules: the verdict, why, the evidence it
    rests on (``Judgement.evidence``) and the path that decided ("" when none)."""

    verdict: Verdict
    reason: str
    evidence: str
    path: str


def resolve_threshold_px(config: VerdictConfig, width: int, height: int) -> float:
    """The PASS threshold in original photo pixels for an image of this size."""
    return config.threshold_for(width, height)


def path_outcome(
    m: FrameMeasurement,
    path: PathMeasurement | None,
    config: VerdictConfig,
    photo_from_render: Any = None,
) -> PathOutcome:
    """Verdict and reason that one path alone gives (``photo_from_render`` overrides the path's
    homography, e.g. after removing a calibration error)."""
    if path is None:
        return PathOutcome(Verdict.UNVERIFIABLE, "not_measured")
    if path.reason:
        return PathOutcome(Verdict.UNVERIFIABLE, path.reason)
    if path.n_inliers < config.min_inliers:
        return PathOutcome(Verdict.UNVERIFIABLE, "too_few_inliers")
    if path.inlier_ratio < config.min_inlier_ratio:
        return PathOutcome(Verdict.UNVERIFIABLE, "low_inlier_ratio")
    err = path.corner_error_px
    if photo_from_render is not None:
        from pgt_check.geometry.homography import corner_error

        err = corner_error(np.asarray(photo_from_render, np.float64), m.width, m.height)
    if err is None or not math.isfinite(err):
        return PathOutcome(Verdict.UNVERIFIABLE, "non_finite_homography")
    threshold = config.threshold_for(m.width, m.height)
    if err <= threshold:
        return PathOutcome(Verdict.PASS, "")
    return PathOutcome(Verdict.FAIL, f"corner_error {err:.1f} px > {threshold:.1f} px")


def decide(m: FrameMeasurement, config: VerdictConfig) -> PathOutcome:
    """Verdict and reason of the deciding path (the one with more inliers) alone.

    Order of checks: measurement error (missing image, internal error), render coverage,
    homography failure of the deciding path, inlier count/ratio, then the threshold. The full
    per-frame judgement with evidence kinds and run-level checks is ``judge``.
    """
    if m.error is not MeasureReason.NONE:
        return PathOutcome(Verdict.UNVERIFIABLE, m.error.value)
    if m.coverage is not None and m.coverage < config.min_coverage:
        return PathOutcome(Verdict.UNVERIFIABLE, MeasureReason.LOW_COVERAGE.value)
    return path_outcome(m, m.chosen, config)


def _reference_off(m: FrameMeasurement, own: Mapping[str, bool] | None) -> str:
    """The id of the enhanced path's reference when its own render is clearly off (else "")."""
    p = m.enhanced
    if own is None or p is None or p.evidence is not Evidence.RELATIVE or not p.reference_id:
        return ""
    return p.reference_id if own.get(p.reference_id) else ""


def _calibrated(
    m: FrameMeasurement, path: PathMeasurement | None, config: VerdictConfig, shared: SharedChecks | None
) -> Any:
    """The path's homography with the camera's estimated calibration error removed, where the
    run-level checks took it out (``run_checks.remove_calibration`` / ``calibration_from``);
    else None."""
    removing = shared is not None and shared.removes_calibration
    if not removing or path is None or path.photo_from_render is None or shared is None:
        return None
    h_cal = shared.calibration_homography(m.frame_id, m.camera_id)
    if h_cal is None or path.evidence is not Evidence.ABSOLUTE:
        return None
    return np.linalg.solve(h_cal, np.asarray(path.photo_from_render, np.float64))


def path_outcomes(
    m: FrameMeasurement,
    config: VerdictConfig,
    shared: SharedChecks | None = None,
    barred: Mapping[str, str] | None = None,
) -> dict[str, PathOutcome | None]:
    """What each path (raw, enhanced, edges) alone says, after removing the camera's estimated
    calibration error from absolute paths when the config asks for it. ``barred``: path ->
    reason, the paths that cannot tell right from wrong on this run
    (``verdict.separation``): their outcome is UNVERIFIABLE with that reason."""
    out: dict[str, PathOutcome | None] = {}
    for name in ("raw", "enhanced", "edges"):
        p = getattr(m, name)
        if p is not None and barred and name in barred:
            out[name] = PathOutcome(Verdict.UNVERIFIABLE, barred[name])
            continue
        h = _calibrated(m, p, config, shared)
        out[name] = None if p is None else path_outcome(m, p, config, h)
    return out


def own_outcome(
    m: FrameMeasurement, outcomes: Mapping[str, PathOutcome | None], config: VerdictConfig
) -> tuple[Verdict, str, str]:
    """What the frame's own render says (absolute evidence only): the raw path when it is
    verifiable with ``confident_inliers``, else the geometric-edge path when verifiable, else a
    raw path with fewer inliers; UNVERIFIABLE when none is. Returns (verdict, reason, path)."""
    raw, edges = outcomes.get("raw"), outcomes.get("edges")

    def ok(o: PathOutcome | None) -> bool:
        return o is not None and o[0] is not Verdict.UNVERIFIABLE

    if raw is not None and ok(raw) and m.raw is not None \
            and m.raw.n_inliers >= config.confident_inliers:
        return raw[0], raw[1], "raw"
    for name, o in (("edges", edges), ("raw", raw)):
        if o is not None and ok(o):
            return o[0], o[1], name
    return Verdict.UNVERIFIABLE, "no_absolute_path", ""


def path_error_px(
    m: FrameMeasurement, name: str, config: VerdictConfig, shared: SharedChecks | None = None
) -> float | None:
    """The named path's corner error as the verdict compares it (the camera's calibration
    error removed where the run removes it), photo px; None when the path has none."""
    p = m.path(name)
    if p is None or p.corner_error_px is None:
        return None
    err = p.corner_error_px
    h = _calibrated(m, p, config, shared)
    if h is not None:
        from pgt_check.geometry.homography import corner_error

        err = corner_error(h, m.width, m.height)
    return float(err)


def _error_ratio(m: FrameMeasurement, name: str, config: VerdictConfig, shared: SharedChecks | None) -> float:
    """The named path's corner error (calibration removed where asked) over the threshold;
    NaN when the path has none."""
    err = path_error_px(m, name, config, shared)
    if err is None:
        return float("nan")
    return err / config.threshold_for(m.width, m.height)


def own_outcomes(
    measurements: Iterable[FrameMeasurement],
    config: VerdictConfig,
    shared: SharedChecks | None = None,
    outcomes: Sequence[Mapping[str, PathOutcome | None]] | None = None,
) -> dict[str, bool]:
    """frame id -> whether its own render is clearly off (``own_outcome`` FAILs with the
    corner error beyond ``1 + CLEAR_MARGIN`` x the threshold, on a raw path with
    ``confident_inliers`` or the edge path), for the reference check: a reference that is only
    near the threshold, or judged by a few raw inliers, still serves. ``outcomes``: the
    frames' ``path_outcomes`` when already computed (same order)."""
    ms = list(measurements)
    outs = outcomes if outcomes is not None else [path_outcomes(m, config, shared) for m in ms]
    out = {}
    for m, o in zip(ms, outs, strict=True):
        verdict, _, name = own_outcome(m, o, config)
        weak = name == "raw" and m.raw is not None and m.raw.n_inliers < config.confident_inliers
        ratio = _error_ratio(m, name, config, shared)
        out[m.frame_id] = verdict is Verdict.FAIL and not weak and ratio > 1.0 + CLEAR_MARGIN
    return out


#: what each path alone says (``path_outcomes``)
_Outcomes = Mapping[str, PathOutcome | None]


def judge(
    m: FrameMeasurement,
    config: VerdictConfig,
    shared: SharedChecks | None = None,
    own: Mapping[str, bool] | None = None,
    outcomes: Mapping[str, PathOutcome | None] | None = None,
) -> Judgement:
    """The frame's verdict from its paths and the run-level checks (``verdict.shared``).

    Rules: a confident FAIL of a feature path (>= ``confident_inliers`` inliers) is a FAIL.
    Otherwise the deciding feature path (more inliers) gives the verdict; where no feature path
    is verifiable, the geometric-edge path does. A PASS needs absolute evidence (an absolute
    path decided, or the raw or edge path also passes), or relative evidence plus a passed
    registration check whose drift score at this frame stays within the drift threshold; a
    relative-only PASS is UNVERIFIABLE (``relative_evidence_only``). A non-confident FAIL
    against another absolute path's PASS: a clear PASS decides, else ``paths_disagree``. A
    failed registration check or a flagged drift segment turns the frames' PASS into FAIL.

    ``own`` (frame id -> its own render is clearly off, ``own_outcomes``): when the
    reprojected reference that decided is clearly off on its own render, the reprojection
    carries the reference's error, so neither its PASS nor its FAIL counts: this frame's own
    render decides, or the frame is UNVERIFIABLE (``reference_off``). ``outcomes``: this
    frame's ``path_outcomes`` when already computed.
    """
    base, why = decide(m, config)
    if m.error is not MeasureReason.NONE or why == MeasureReason.LOW_COVERAGE.value:
        return Judgement(base, why, "none", "", "")
    out = outcomes if outcomes is not None else path_outcomes(m, config, shared)
    raw_v = "" if out["raw"] is None else out["raw"][0].value
    enh_v = "" if out["enhanced"] is None else out["enhanced"][0].value
    ref_off = _reference_off(m, own)
    (verdict, reason, evidence, path), final = _paths_decision(
        m, config, shared, out, ref_off, PathOutcome(base, why)
    )
    err = path_error_px(m, path, config, shared)
    own_v = own_outcome(m, out, config)[0].value
    if final or verdict is not Verdict.PASS:
        return Judgement(verdict, reason, evidence, raw_v, enh_v, path, err, own_v)
    run_level = _run_level(m.frame_id, shared, evidence, _absolute_pass(out), m.camera_id)
    return Judgement(*run_level, raw_v, enh_v, path, err, own_v)


def _paths_decision(
    m: FrameMeasurement,
    config: VerdictConfig,
    shared: SharedChecks | None,
    out: _Outcomes,
    ref_off: str,
    base: PathOutcome,
) -> tuple[Decision, bool]:
    """(decision, final) from the frame's paths, before the run-level checks (``judge``);
    final: no run-level check applies. ``base``: what ``decide`` says."""
    confident = _confident_fail(m, config, out, ref_off)
    if confident is not None:
        return confident, True
    d = _deciding_path(m, out, base)
    if ref_off and d.evidence == Evidence.RELATIVE.value:
        d, final = _without_reference(m, config, out, ref_off, d)
        if final:
            return d, True
    d = _edges_if_unverifiable(out, d)
    return _settle_disagreement(m, config, shared, out, d)


def _confident_fail(
    m: FrameMeasurement, config: VerdictConfig, out: _Outcomes, ref_off: str
) -> Decision | None:
    """A FAIL of a feature path with ``confident_inliers`` (None when there is none)."""
    for name in ("raw", "enhanced"):
        p, o = m.path(name), out[name]
        if o and o[0] is Verdict.FAIL and p is not None \
                and p.n_inliers >= config.confident_inliers:
            if ref_off and p.evidence is Evidence.RELATIVE:
                continue  # the reference's own error explains it
            return Decision(Verdict.FAIL, o[1], p.evidence.value, name)
    return None


def _deciding_path(m: FrameMeasurement, out: _Outcomes, base: PathOutcome) -> Decision:
    """What the deciding path says (``base`` when it has no outcome): the measurement's
    ``verdict_path``, or the other feature path when that one cannot separate on this run
    (``verdict.separation``) and the other gives a PASS or FAIL."""
    name = m.verdict_path or ""
    o = out.get(name)
    if o is not None and o[1].startswith(CANNOT_SEPARATE):
        other = {"raw": "enhanced", "enhanced": "raw"}.get(name, "")
        oo = out.get(other)
        if oo is not None and oo[0] is not Verdict.UNVERIFIABLE:
            name = other
    chosen = getattr(m, name, None) if name else None
    evidence = "none" if chosen is None else chosen.evidence.value
    verdict, reason = out.get(name) or base
    return Decision(verdict, reason, evidence, name)


def _without_reference(
    m: FrameMeasurement,
    config: VerdictConfig,
    out: _Outcomes,
    ref_off: str,
    d: Decision,
) -> tuple[Decision, bool]:
    """(decision, final) where the reference that decided is clearly off on its own render."""
    # a reference that its own render shows off cannot vouch for or against this frame:
    # what this frame's own render says decides (absolute evidence; demanding a clear PASS
    # there made correct frames next to a wrong one UNVERIFIABLE: reports/edge_pipeline.md)
    base, why, own_path = own_outcome(m, out, config)
    off = f"reference {ref_off} fails on its own render"
    if base is Verdict.UNVERIFIABLE:
        return Decision(base, f"reference_off ({off})", d.evidence, d.path), True
    return Decision(base, why, Evidence.ABSOLUTE.value, own_path), False


def _edges_if_unverifiable(out: _Outcomes, d: Decision) -> Decision:
    """The geometric-edge path's PASS or FAIL where the decision so far is UNVERIFIABLE."""
    edges = out["edges"]
    if d.verdict is Verdict.UNVERIFIABLE and edges is not None and edges.verdict in (
            Verdict.PASS, Verdict.FAIL):
        return Decision(edges.verdict, edges.reason, Evidence.ABSOLUTE.value, "edges")
    return d


def _settle_disagreement(
    m: FrameMeasurement, config: VerdictConfig, shared: SharedChecks | None, out: _Outcomes, d: Decision
) -> tuple[Decision, bool]:
    """(decision, final) of a FAIL that another absolute path's PASS contradicts."""
    base, why, evidence, path = d
    passing = [
        n for n in ("raw", "edges")
        if n != path and (o := out[n]) is not None and o[0] is Verdict.PASS
    ]
    if base is not Verdict.FAIL or not passing:
        return d, False
    # a FAIL that is not confident against a PASS of another absolute path: a clear PASS
    # (within half the threshold) decides. A reprojected reference's FAIL is relative
    # evidence (the reference's pose error and the mesh's geometry between the two views
    # are in it): any absolute PASS outweighs it; on TSDF-fused scans it failed correct
    # frames whose edges passed (reports/edge_pipeline.md). A render's FAIL on few inliers
    # against a PASS that is not clear: the paths disagree
    clear = [n for n in passing if _error_ratio(m, n, config, shared) <= 1.0 - CLEAR_MARGIN]
    if evidence == Evidence.RELATIVE.value:
        clear = clear or passing
    if not clear:
        reason = f"paths_disagree ({why} on the {path} path; an absolute path passes)"
        return Decision(Verdict.UNVERIFIABLE, reason, evidence, path), True
    chosen = out[clear[0]]
    assert chosen is not None  # it passes
    base, why = chosen
    return Decision(base, why, Evidence.ABSOLUTE.value, clear[0]), False


def _absolute_pass(out: _Outcomes) -> bool:
    """The raw or the geometric-edge path passes on its own."""
    raw_v = "" if out["raw"] is None else out["raw"][0].value
    edge_v = None if out["edges"] is None else out["edges"][0]
    return Verdict.PASS.value in (raw_v, edge_v and edge_v.value)


def _run_level(
    frame_id: str, shared: SharedChecks | None, evidence: str, absolute_pass: bool, camera_id: str = ""
) -> tuple[Verdict, str, str]:
    """(verdict, reason, evidence) of a frame whose paths PASS, after the run-level checks:
    a flagged drift segment, a failed registration or (``--calibration-from``) a camera whose
    calibration changed since the trusted run makes it FAIL; relative evidence needs a
    passed registration check, the frame's own evidence consistent with it and the drift here
    within the threshold."""
    if shared is not None and frame_id in shared.drift_flagged:
        px = shared.drift_px.get(frame_id, float("nan"))
        return Verdict.FAIL, f"drift: this segment moves {px:.1f} px off the mesh", evidence
    reg = NOT_CHECKED if shared is None else shared.registration_status
    if reg == FAILED:
        assert shared is not None  # it was checked
        e = shared.registration if shared.registration.status == FAILED else shared.similarity
        return (
            Verdict.FAIL,
            f"registration: trajectory off the mesh by {e.effect_px:.1f} "
            f"px ({e.angle_deg:.2f} deg)",
            evidence,
        )
    changed = None if shared is None else shared.calibration_changed(camera_id)
    if changed is not None:
        return (
            Verdict.FAIL,
            f"calibration: this camera changed since the trusted run ({changed.effect_px:.1f} "
            "px)",
            evidence,
        )
    if evidence == Evidence.ABSOLUTE.value:
        return Verdict.PASS, "", evidence
    if absolute_pass:  # an absolute path confirms the relative PASS
        return Verdict.PASS, "", Evidence.ABSOLUTE.value
    drift = np.nan if shared is None else shared.drift_px.get(frame_id, np.nan)
    if reg == PASSED and shared is not None and frame_id not in shared.left_out \
            and not drift > shared.drift_threshold_px:
        return Verdict.PASS, "", "relative+registration"
    if reg == PASSED and shared is not None and drift > shared.drift_threshold_px:
        # the run-level checks do not vouch for this part of the trajectory: its drift score
        # is above the threshold, only not significantly
        reg = f"passed, but the trajectory here drifts by {drift:.1f} px, not confirmed"
    elif reg == PASSED:  # its own absolute evidence disagrees with the registered trajectory
        reg = "passed, but this frame's absolute evidence disagrees with it"
    return Verdict.UNVERIFIABLE, f"relative_evidence_only (registration {reg})", evidence
