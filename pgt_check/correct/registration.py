"""The registration estimate refined by measuring again at the corrected poses (a correction
step after the verdicts; ``run_checks.refine_rounds``).

When the run-level registration check fails, its estimate comes from evidence measured at the
misregistered poses. Where the misregistration moves the images non-uniformly (the zoom and
parallax of a translation) the per-frame edge alignment stops short of the far-off edges, and
the pooled fit trades part of the translation for a rotation (a castle trajectory moved along
the depth is estimated mostly as a rotation: reports/shared_errors.md). The image effect of
the estimate is right (what the check decides on); its split is not.

Each round moves the checked frames by the correction estimated so far, measures their
absolute evidence again (render, raw match, geometric edges; no enhancement, whose evidence is
relative) and fits the correction that is left; the total is the composition (outer
Gauss-Newton iterations). The remaining motion shrinks every round, where the alignment is
unbiased (reports/shared_errors.md, refinement).

By default the refinement is deferred (``run_checks.refine_rounds`` 0: the registration entry
says so, and ``--registration-rounds 8 --resume`` measures only the rounds). The rounds are
bounded (issue #28: a run that fails pays only for what it reports): at most
``run_checks.refine_rounds`` rounds, at most ``correct.budget`` times the main
pass's measuring time, and they stop when what is left grows from one round to the next beyond
the evidence's noise (its 95 % interval wholly above the last one; the
estimate does not converge: the one before the update that made it grow is kept). Where the
views cannot separate the registration from a calibration error each round may re-decide which
of the two the shared error is: on the 7-Scenes sweep failing on its calibration offset the
rounds oscillated (reports/pipeline_timing.md); they now stop at the first growth with the
estimate before it kept. ``refinement.stopped`` in the summary says which rule ended the
rounds, ``refinement.rounds_kept`` how many updates the estimate holds.

The frames' verdicts stay those of the main pass (the run is misregistered either way); the
summary's registration entry gets the refined correction (the first estimate under
``refinement.first_pass``; the similarity entry keeps its own), and
``registered_trajectory.txt`` holds every frame moved by
the refined rigid correction. ``registration_refined.json`` keeps the result: ``pgt-check
report`` and ``--resume`` reuse it while the main pass's estimate is the one it started from.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from pgt_check.config import RunConfig
from pgt_check.correct.registration_result import (  # noqa: F401  (re-exported)
    SAME_START_ATOL,
    RefinedRegistration,
    RefineRound,
    _summary_of,
    apply_refinement,
    load_refinement,
    refined_registration,
    registered_trajectory,
    registration_entries,
    save_refinement,
)
from pgt_check.geometry.transforms import move_pose
from pgt_check.measure.record import FrameMeasurement
from pgt_check.output_layout import OUTPUTS
from pgt_check.types import Frame, Trajectory
from pgt_check.verdict.shared import SharedChecks
from pgt_check.verdict.shared_results import RegistrationCheck
from pgt_check.verdict.status import FAILED, PASSED

logger = logging.getLogger(__name__)

#: rounds stop early once the correction left moves the images by less than this share of
#: the shared threshold, or passes the shared threshold in two rounds in a row (further
#: rounds would follow the evidence's noise)
CONVERGED_REL = 0.25

#: a round's residual may be this much larger than the round before's and still count as
#: converging (the evidence's noise); beyond it the rounds stop as "not converging"
GROWTH_TOLERANCE = 1.0

MeasureFn = Callable[[Sequence[Frame], RunConfig], list[FrameMeasurement]]


def _grew(
    prev: float | None, prev_ci: Any, effect: float | None, effect_ci: Any
) -> bool:
    """What is left grew from one round to the next beyond the evidence's noise: larger than
    ``GROWTH_TOLERANCE`` x before and, where both rounds have a 95 % interval, with the new
    interval wholly above the old one (a growth within overlapping intervals is noise, and
    stopping there kept much of a moved 7-Scenes trajectory's error: reports/shared_errors.md)."""
    if prev is None or effect is None or not effect > GROWTH_TOLERANCE * prev:
        return False
    try:
        lo, hi = float(effect_ci[0]), float(prev_ci[1])
    except (TypeError, IndexError, ValueError):
        return True  # no intervals: the sizes decide
    return not (math.isfinite(lo) and math.isfinite(hi)) or lo > hi


def needs_refinement(shared: SharedChecks) -> bool:
    """The rigid or the similarity check FAILED and the rigid fit has a correction."""
    reg, sim = registration_entries(shared)
    return FAILED in (reg.status, sim.status) and reg.corrected_world_from_world is not None


def refine_frames(
    measurements: Sequence[FrameMeasurement], frames: Sequence[Frame], max_frames: int
) -> list[Frame]:
    """The frames measured again: every measured frame, at most ``max_frames`` evenly spaced
    along the trajectory (those with absolute evidence in the main pass first). Frames the
    main pass left out of the pooled fit are not excluded: at misregistered poses the edge
    alignment's bias differs from frame to frame, and most frames of a moved 7-Scenes
    trajectory looked like errors of their own (reports/shared_errors.md); each round decides
    again which frames agree."""
    by_id = {f.frame_id: f for f in frames}
    usable = [m for m in measurements if m.frame_id in by_id]
    with_ev = [m for m in usable if m.evidence is not None]
    pool = with_ev if len(with_ev) >= min(max_frames, len(usable)) else usable
    if len(pool) > max_frames:
        keep = np.linspace(0, len(pool) - 1, max_frames).round().astype(int)
        pool = [pool[i] for i in keep]
    return [by_id[m.frame_id] for m in pool]


def evidence_config(config: RunConfig) -> RunConfig:
    """The main config for absolute evidence only: no enhancement, no report panels, and no
    cross-validated edge refit where the fixed model fails (``edges.select_model`` fallback
    changes a frame's verdict, not the evidence the rounds' pooled fit uses wherever the fixed
    alignment is accepted). The verdict settings, calibration handling included, stay."""
    edges = config.edges
    if edges.select_model == "fallback":
        edges = replace(edges, select_model="never")
    return replace(config, enhance=replace(config.enhance, mode="never"), edges=edges,
                   report_details=0)


def refine_fingerprint(config: RunConfig) -> str:
    """What a stored refinement depends on: the measurement, verdict and correction settings."""
    return config.measurement_fingerprint(verdict=config.verdict, run_checks=config.run_checks,
                                        correct=config.correct)


def _f(x: Any) -> float | None:
    return None if x is None or not math.isfinite(float(x)) else float(x)


def _measure_round(
    k: int, todo: Sequence[Frame], c_rigid: np.ndarray, measure: MeasureFn, ecfg: RunConfig,
    clock: Callable[[], float] = time.perf_counter,
) -> tuple[RefineRound, SharedChecks]:
    """Round ``k``: the frames moved by ``c_rigid`` measured again and the shared checks run on
    them; the round's record and the checks (their registration entry: what is left)."""
    from pgt_check.verdict.shared import run_shared_checks

    t0 = clock()
    moved = [f.with_pose(move_pose(f.world_from_cam, c_rigid)) for f in todo]
    ms = measure(moved, ecfg)
    order = {f.frame_id: i for i, f in enumerate(moved)}
    ms = sorted(ms, key=lambda m: order.get(m.frame_id, len(order)))
    res = run_shared_checks(ms, ecfg)
    reg = res.registration
    rnd = RefineRound(
        k, len(ms), sum(m.evidence is not None for m in ms), str(reg.status),
        _f(reg.angle_deg), reg.angle_deg_ci, _f(reg.translation), reg.translation_ci,
        _f(reg.effect_px), reg.effect_px_ci, clock() - t0,
    )  # fmt: skip
    logger.info(
        "registration round %d: what is left moves the images by %s px (%s)",
        k,
        "?" if rnd.effect_px is None else f"{rnd.effect_px:.2f}",
        reg.status,
    )
    return rnd, res


@dataclass(frozen=True)
class _Rounds:
    """What every round of ``refine_registration`` works with."""

    todo: Sequence[Frame]  # the frames measured again
    ecfg: RunConfig  # ``evidence_config`` of the run's config
    measure: MeasureFn
    clock: Callable[[], float]
    origin: np.ndarray  # (3,) mean camera centre, where the totals are summarised
    budget: float  # seconds the rounds may take; 0: no limit
    budget_factor: float  # ``correct.budget`` (for the message)
    t_start: float  # ``clock()`` when the rounds started
    first: RegistrationCheck  # the main pass's registration entry


def refine_registration(
    frames: Sequence[Frame],
    measurements: Sequence[FrameMeasurement],
    shared: SharedChecks,
    config: RunConfig,
    measure: MeasureFn,
    clock: Callable[[], float] = time.perf_counter,
) -> RefinedRegistration | None:
    """Rounds of measure-at-the-corrected-poses -> residual fit -> compose (module docstring).

    ``shared``: the main pass's run-level checks; ``measure(frames, config)``: the absolute
    evidence of the frames at their (moved) poses, in any order. None when there is nothing to
    refine (``needs_refinement`` false, rounds 0, or no frame to measure). Bounded by
    ``run_checks.refine_rounds``, ``correct.budget`` and the growth rule (module
    docstring); ``clock`` (seconds) is replaceable for tests."""
    c = config.run_checks
    rounds = c.refine_rounds
    if rounds <= 0 or not needs_refinement(shared):
        return None
    todo = refine_frames(measurements, frames, c.refine_frames)
    if len(todo) < 3:
        return None
    ecfg = evidence_config(config)
    first = registration_entries(shared)[0]
    start = np.asarray(first.corrected_world_from_world, np.float64)
    centres = [np.asarray(m.world_from_cam)[:3, 3] for m in measurements if m.world_from_cam]
    origin = np.mean(centres, axis=0)
    budget = config.correct.budget * main_pass_seconds(measurements)
    t_start = clock()
    r = _Rounds(todo, ecfg, measure, clock, origin, budget, config.correct.budget, t_start, first)
    logger.info(
        "registration check failed: refining its estimate (up to %d round(s) of "
        "measuring %d frames again at the corrected poses%s)",
        rounds,
        len(todo),
        f", at most {budget:.0f} s" if budget > 0 else "",
    )
    c_rigid, done, stopped, kept = _run_rounds(r, start, rounds)
    logger.info("registration refinement: %d round(s) in %.1f s, %s", len(done),
                clock() - t_start, stopped)
    return RefinedRegistration(
        start=start.tolist(),
        rigid=c_rigid.tolist(),
        origin=origin.tolist(),
        rounds=tuple(done),
        stopped=stopped,
        fingerprint=refine_fingerprint(config),
        frame_ids=tuple(f.frame_id for f in todo),
        kept=kept,
    )


def _run_rounds(
    r: _Rounds, start: np.ndarray, rounds: int
) -> tuple[np.ndarray, list[RefineRound], str, int | None]:
    """Up to ``rounds`` rounds from the correction ``start`` (4, 4): (the correction kept,
    the rounds' records, why they stopped, the updates kept where the rounds diverged)."""
    c_rigid = start.copy()
    history = [start.copy()]  # history[k]: the correction after k rounds' updates
    done: list[RefineRound] = []
    for k in range(1, rounds + 1):
        stopped = _out_of_time(r, k, done)
        if stopped is not None:
            return c_rigid, done, stopped, None
        rnd, res = _measure_round(k, r.todo, c_rigid, r.measure, r.ecfg, r.clock)
        reg = res.registration
        done.append(rnd)
        prev, prev_ci = _left_before(r, done)
        if _grew(prev, prev_ci, rnd.effect_px, rnd.effect_px_ci):
            # the last update moved the poses further from what the evidence says: the
            # estimate does not converge (an ill-posed split); keep the one before it
            kept = max(k - 2, 0)
            assert prev is not None and rnd.effect_px is not None  # ``_grew`` compared them
            return history[kept], done, _not_converging(prev, rnd.effect_px, k), kept
        if reg.corrected_world_from_world is None:
            stopped = f"round {k}: no residual fit ({reg.reason or reg.status})"
            return c_rigid, done, stopped, None
        c_rigid = np.asarray(reg.corrected_world_from_world, np.float64) @ c_rigid
        history.append(c_rigid.copy())
        total_angle, total_t, _ = _summary_of(c_rigid, r.origin)
        done[-1] = replace(done[-1], total_angle_deg=total_angle, total_translation=total_t)
        stopped = _converged(done, res)
        if stopped is not None:
            return c_rigid, done, stopped, None
    return c_rigid, done, "round limit", None


def _out_of_time(r: _Rounds, k: int, done: Sequence[RefineRound]) -> str | None:
    """Why round ``k`` is not started: one more round as long as the last would pass the
    budget; None when it may start."""
    if k > 1 and r.budget > 0 and r.clock() - r.t_start + done[-1].time_s > r.budget:
        return (f"time limit: {k - 1} round(s) took {r.clock() - r.t_start:.1f} s of the "
                f"{r.budget:.1f} s budget (correct.budget "
                f"{r.budget_factor:g} x the main pass)")
    return None


def _left_before(r: _Rounds, done: Sequence[RefineRound]) -> tuple[float | None, Any]:
    """What was left before the last round (px) and its 95 % interval."""
    # round 1 against the main pass: the first estimate's poses against the checked ones
    if len(done) >= 2:
        return done[-2].effect_px, done[-2].effect_px_ci
    return _f(r.first.effect_px), r.first.effect_px_ci


def _not_converging(prev: float, effect: float, k: int) -> str:
    """Why the rounds stopped when what is left grew from ``prev`` to ``effect`` in round k."""
    return (f"not converging: what is left grew from {prev:.1f} px to "
            f"{effect:.1f} px in round {k}; " + (
                f"the estimate measured in round {k - 1} is kept" if k > 1 else
                "the first estimate moved the poses further off than they were; "
                "it is reported unrefined"))


def _converged(done: Sequence[RefineRound], res: SharedChecks) -> str | None:
    """Why the rounds stop after the last one (``res``: its shared checks), or None."""
    eff = done[-1].effect_px
    if eff is not None and eff < CONVERGED_REL * float(res.threshold_px):
        return "converged"
    if len(done) >= 2 and done[-1].status == done[-2].status == PASSED:
        # what is left is below the shared threshold twice in a row: the noise of the
        # evidence, which further rounds would only follow
        return "converged (passed twice)"
    return None


def main_pass_seconds(measurements: Sequence[FrameMeasurement]) -> float:
    """The main pass's measuring time: the frames' summed ``timings.total`` (0 when not
    recorded)."""
    total = 0.0
    for m in measurements:
        t = getattr(m.timings, "total", None)
        if t is not None and math.isfinite(float(t)):
            total += float(t)
    return total


def refine_run(
    trajectory: Trajectory,
    measurements: Sequence[FrameMeasurement],
    shared: SharedChecks,
    config: RunConfig,
    measure: MeasureFn,
    out: str | Path,
) -> SharedChecks:
    """The correction step for a failed registration check: reuse the stored refinement of
    this start or run the rounds, save it, write ``registered_trajectory.txt``; returns
    ``shared`` (the main pass's run-level checks) with the refined correction."""
    from pgt_check.io.writers import write_trajectory_file

    out = Path(out)
    refined = None
    if config.run_checks.refine_rounds > 0 and needs_refinement(shared):
        refined = load_refinement(out, shared, refine_fingerprint(config))
        if refined is not None:
            logger.info("registration refinement reused from %s",
                        out / OUTPUTS.registration_refined)
        else:
            refined = refine_registration(trajectory.frames, measurements, shared, config, measure)
            if refined is not None:
                save_refinement(out, refined)
    path = out / OUTPUTS.registered_trajectory
    if refined is None:
        path.unlink(missing_ok=True)  # a previous run's file would no longer be true
        if config.run_checks.refine_rounds == 0 and needs_refinement(shared):
            return _deferred(shared)
        return shared
    write_trajectory_file(registered_trajectory(trajectory, refined), path)
    return apply_refinement(shared, refined)


#: what the registration entry of a failed check says where the refinement is deferred
DEFERRED = ("Not refined (run_checks.refine_rounds 0): the split between rotation and "
            "translation of a first estimate can be off where the misregistration zooms the "
            "images; --registration-rounds 8 --resume refines it (only the rounds are measured) "
            "and writes registered_trajectory.txt")


def _deferred(shared: SharedChecks) -> SharedChecks:
    """``shared`` with the rigid registration entry saying that its refinement was deferred."""
    reg = shared.registration
    if reg.corrected_world_from_world is None or DEFERRED in reg.message:
        return shared
    return shared.with_entries(registration=replace(reg, message=f"{reg.message}. {DEFERRED}"))
