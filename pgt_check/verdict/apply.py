"""Stage 2 over a run: run-level checks, then each stored measurement's verdict, as a typed
``RunResult`` (``verdict.result``)."""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import replace
from typing import Any

from pgt_check.config.judge import JudgingConfig
from pgt_check.enhance.base import Evidence
from pgt_check.measure.record import FrameMeasurement
from pgt_check.verdict.decide import judge, own_outcomes, path_outcomes
from pgt_check.verdict.frame_bounds import (
    agreeing_paths,
    bounded_pass,
    frame_bounds,
    pass_bound,
    trusted_calibrations,
    world_sensitivity,
)
from pgt_check.verdict.judgement import CANNOT_SEPARATE, Judgement, Verdict
from pgt_check.verdict.off_mesh import off_mesh_frames
from pgt_check.verdict.result import FrameResult, RunResult
from pgt_check.verdict.separation import Probe, path_separation
from pgt_check.verdict.shared import run_shared_checks
from pgt_check.verdict.shared_results import Sensitivity
from pgt_check.verdict.status import NOT_CHECKED
from pgt_check.verdict.vouching import vouched_frames, vouched_reference


def judge_run(
    measurements: Iterable[FrameMeasurement],
    config: JudgingConfig,
    probes: Sequence[Probe] | None = None,
) -> RunResult:
    """Run-level checks on all measurements (trajectory order), then each frame's judgement;
    a frame below ``min_coverage`` whose neighbours see the mesh well FAILs ``off_mesh``
    (``pgt_check.verdict.off_mesh``). ``probes``: frames moved by known amounts and measured
    again (``verdict.separation``): a path that does not separate them from the given poses
    decides no frame (``path_cannot_separate``).

    Measurements are not changed (records.jsonl stays as measured)."""
    ms = list(measurements)
    v = config.verdict
    sep = path_separation(ms, probes or (), v)
    barred = sep.barred
    # a path that cannot tell right from wrong on this run gives no evidence to the pooled
    # checks either (its points would pull the registration / calibration estimates)
    shared = (run_shared_checks(ms, config, exclude_paths=tuple(barred))
              if config.run_checks.enabled and ms else None)
    if shared is not None and shared.registration.status != NOT_CHECKED:
        # what a world rotation / translation does to the images (the shared detection limit)
        sens = Sensitivity(*world_sensitivity(ms))
        shared = shared.with_entries(registration=replace(shared.registration, sensitivity=sens))
    outs = [path_outcomes(m, v, shared, barred) for m in ms]
    own = own_outcomes(ms, v, shared, outs)
    judged = [judge(m, v, shared, own, out) for m, out in zip(ms, outs, strict=True)]
    # a render that shows (almost) nothing of a mesh its neighbours see well: a gross pose
    # error, not missing evidence (``verdict.off_mesh``)
    off = off_mesh_frames(ms, v.min_coverage)
    judged = [
        Judgement(Verdict.FAIL, off[m.frame_id], Evidence.ABSOLUTE.value, "", "")
        if m.frame_id in off else j
        for m, j in zip(ms, judged, strict=True)
    ]
    # second pass: a frame judged through a reference that does not vouch (``verdict.vouching``:
    # PASS on its own absolute evidence) is judged through another tried reference that does,
    # where one aligned
    vouched = vouched_frames(ms, judged)
    final = []
    for m, j, out in zip(ms, judged, outs, strict=True):
        m2 = vouched_reference(m, j, vouched, v)
        if m2 is not None:
            out = path_outcomes(m2, v, shared, barred)
            m, j = m2, judge(m2, v, shared, own, out)
        final.append((m, j, out))
    # the pose accuracy each frame's absolute evidence supports (``verdict.frame_bounds``), after
    # taking out the calibration error the verdicts take out, from the paths that agree with
    # its verdict (a path the verdict overruled measures its own error, not the pose's)
    cals = (shared.removed_calibrations if shared is not None
            else trusted_calibrations(config.run_checks, [m.camera_id for m in ms]))
    agree = {m.frame_id: agreeing_paths(out, j.decided_by) for m, j, out in final}
    bounds = frame_bounds(ms, cals, agree)
    frames = []
    for i, (m, j, _) in enumerate(final):
        drift = None if shared is None else shared.drift_px.get(m.frame_id)
        b, thr = bounds[m.frame_id], v.threshold_for(m.width, m.height)
        # a PASS and its 95 % bound agree, or the frame is UNVERIFIABLE; the bound from all the
        # evidence the PASS rests on (``pass_bound``)
        if j.verdict is Verdict.PASS and b.bounded and b.accuracy is not None and (
                b.accuracy.effect_bound_px > thr):
            b = pass_bound(m, i, b, cals.get(m.camera_id) if cals else None,
                           agree.get(m.frame_id))
        bound = b.accuracy.effect_bound_px if b.bounded and b.accuracy is not None else None
        j = bounded_pass(j, bound, thr)
        frames.append(FrameResult(m, j, thr, drift, b))
    n_barred = sum(f.reason.startswith(CANNOT_SEPARATE) for f in frames)
    separation = replace(sep, barred_frames=n_barred) if sep.paths else None
    return RunResult(tuple(frames), shared, separation)


def apply_verdicts(
    measurements: Iterable[FrameMeasurement], config: JudgingConfig
) -> list[dict[str, Any]]:
    """The frames.csv rows of ``judge_run`` (for the pandas API and the comparison)."""
    return judge_run(measurements, config).rows()
