"""The stages after the verdicts that measure frames again: the correction stage
(``pgt_check.correct``: a failed registration check's estimate refined, corrected poses of the
chosen frames) and the self-test of the stated detection limits (``verdict.self_test``), with
``PlainMeasure``, the measure function both hand frames to.
"""

from __future__ import annotations

import functools
import logging
from collections.abc import Callable, Mapping, Sequence
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

from pgt_check.config import RunConfig
from pgt_check.errors import InputError, RunInterrupted
from pgt_check.measure import FrameMeasurement, build_frame_checker
from pgt_check.measure.steps import format_exception
from pgt_check.output_layout import OUTPUTS
from pgt_check.progress import frame_progress
from pgt_check.types import Frame, Trajectory

if TYPE_CHECKING:
    from pgt_check.correct.calibration import CalibratedRig
    from pgt_check.correct.correction import Correction
    from pgt_check.correct.result import CorrectedRun
    from pgt_check.executor import CheckerLender
    from pgt_check.verdict.result import RunResult
    from pgt_check.verdict.shared import SharedChecks

logger = logging.getLogger(__name__)

__all__ = ["PlainMeasure", "correct_stage", "self_test_stage", "separation_stage"]


def correct_stage(
    traj: Trajectory,
    measurements: list[FrameMeasurement],
    judged: RunResult,
    config: RunConfig,
    checker_factory: Callable[[], Any],
) -> CorrectedRun:
    """The correction stage (``pgt_check.correct``) on the verdict stage's result: a failed
    registration check's estimate refined, a significant calibration estimate written as a rig
    (``calibrated/``), then the corrected poses of the chosen frames."""
    from pgt_check.correct.result import CorrectedRun

    out = Path(config.out)
    shared = judged.shared
    if shared is not None:  # a failed registration check: its estimate refined
        shared = _refined(traj, measurements, shared, config, out)
    rig = _calibrated_rig(traj, judged.shared, config, out, measurements)
    corrections: dict[str, Correction] = {}
    summary = None
    if config.correct.frames != "none":  # corrected poses (pgt_check.correct.frames)
        from pgt_check.correct.frames import correct_run

        corrections, summary = correct_run(traj, measurements, judged, config,
                                           checker_factory, out)
    return CorrectedRun.of(judged, reported_shared=shared, calibrated_rig=rig,
                           corrections=corrections, corrections_summary=summary)


def _refined(traj: Trajectory, measurements: list[FrameMeasurement], shared: SharedChecks,
             config: RunConfig, out: Path) -> SharedChecks:
    """``shared`` with a failed registration check's estimate refined (``correct.registration``);
    ``shared`` itself when the refinement fails (logged; raised with ``fail_fast``)."""
    from pgt_check.correct.registration import refine_run

    measure = PlainMeasure()
    try:
        return refine_run(traj, measurements, shared, config, measure, out)
    except RunInterrupted:
        raise
    except Exception as err:  # the verdicts and the first estimate stand without it
        if config.fail_fast:
            raise
        logger.error("the registration refinement failed (%s); the first estimate is "
                     "reported", format_exception(err))
        return shared
    finally:
        measure.close()


def _calibrated_rig(traj: Trajectory, shared: SharedChecks | None, config: RunConfig,
                    out: Path, measurements: Sequence[FrameMeasurement] = ()
                    ) -> CalibratedRig | None:
    """A significant calibration estimate written exactly, as a rig (``correct.calibration``:
    the measurements' evidence picks the form); None when there is none or it cannot be
    written (logged; raised with ``fail_fast``)."""
    from pgt_check.correct.calibration import write_calibrated_rig

    try:
        return write_calibrated_rig(traj, shared, out, measurements)
    except (OSError, ValueError, InputError) as err:  # the verdicts stand without it
        if config.fail_fast:
            raise
        logger.error("calibrated/ could not be written (%s)", err)
        return None


def self_test_stage(traj: Trajectory, result: CorrectedRun, config: RunConfig) -> CorrectedRun:
    """``result`` with its ``self_test``: ``config.self_test`` frames measured again at poses
    moved around this run's stated detection limits (``pgt_check.verdict.self_test``)."""
    from pgt_check.verdict.accuracy import run_accuracy
    from pgt_check.verdict.self_test import run_self_test

    threshold = result.frames[0].threshold_px if result.frames else 0.0
    acc = run_accuracy(result, result.shared_as_reported, config, threshold)
    measure = PlainMeasure("pgt-check self-test")
    try:
        st = run_self_test(traj.frames, result, acc.limits, config, measure, config.self_test)
    finally:
        measure.close()
    logger.info("%s", st.sentence)
    return replace(result, self_test=st)


def reference_stage(
    trajectory: Trajectory, frames: Sequence[Frame], measurements: Sequence[FrameMeasurement],
    config: RunConfig,
) -> tuple[dict[str, tuple[Frame, ...]], dict[str, FrameMeasurement]]:
    """The reference pass: the ``frames`` whose enhanced path leaned on a reference whose own
    absolute evidence did not pass (``enhance.refs.verified_references``, on a first judgement
    of ``measurements``) measured again with references among the frames whose evidence did.
    -> (frame id -> its new references, frame id -> its new measurement); empty when the
    enhanced path is off or no frame needs it. The runner stores the new measurements
    (``runner._reference_pass``); benchmarks judge them as a run does."""
    from pgt_check.enhance.refs import verified_references
    from pgt_check.verdict import judge_run

    if config.enhance.mode == "never" or not measurements:
        return {}, {}
    refs = verified_references(trajectory, judge_run(measurements, config), config)
    if not refs:
        return {}, {}
    todo = [f for f in frames if f.frame_id in refs]
    logger.info("%d frames leaned on a reference whose own absolute evidence did not pass: "
                "measured again with references that passed (%d without one)", len(todo),
                sum(not r for r in refs.values()))
    measure = PlainMeasure("pgt-check references", refs)
    try:
        got = {m.frame_id: m for m in measure(todo, config)}
    finally:
        measure.close()
    return refs, got


def separation_stage(traj: Trajectory, measurements: Sequence[FrameMeasurement],
                     config: RunConfig, fingerprint: str = "") -> list[Any]:
    """Frames moved by a known amount and measured again through each path that decides
    frames (``verdict.separation``): the probes ``judge_run`` tests each path's separating
    power with. Stored in the run folder (``OUTPUTS.separation_probes``, for ``pgt-check report``);
    probes stored under the same ``fingerprint`` for the same moves are reused (``--resume``).
    [] when ``verdict.separation_frames`` is 0 or no path has enough frames (a stale file is
    removed)."""
    import numpy as np

    from pgt_check.verdict.self_test import ROTATION, moved_frame
    from pgt_check.verdict.separation import (
        Probe,
        load_probes,
        probe_plan,
        save_probes,
    )

    out = Path(config.out)
    jobs = probe_plan(measurements, config.verdict, config.verdict.separation_frames)
    if not jobs:
        (out / OUTPUTS.separation_probes).unlink(missing_ok=True)
        return []
    try:
        stored = {p.job.key: p for p in load_probes(out, fingerprint)}
    except (OSError, ValueError, KeyError, TypeError, InputError):
        stored = {}
    if all(j.key in stored and stored[j.key].job == j for j in jobs):
        return [stored[j.key] for j in jobs]
    by_id = traj.by_id()
    frames, refs = [], {}
    for j in jobs:
        moved = moved_frame(by_id[j.frame_id], ROTATION, j.angle_deg, np.asarray(j.axis))
        frames.append(replace(moved, frame_id=j.key))
        if j.reference_id and j.reference_id in by_id:
            refs[j.key] = (by_id[j.reference_id],)
    paths = {p for j in jobs for p in j.paths}
    cfg = replace(
        config, report_details=0,
        enhance=replace(config.enhance, mode="always" if "enhanced" in paths else "never"),
        edges=replace(config.edges, mode="always" if "edges" in paths else config.edges.mode),
    )
    logger.info("separation check: %d frames measured again at poses moved by a known "
                "amount (paths: %s)", len(frames), ", ".join(sorted(paths)))
    measure = PlainMeasure("pgt-check separation", refs)
    try:
        got = {m.frame_id: m for m in measure(frames, cfg)}
    finally:
        measure.close()
    probes = [Probe(j, replace(got[j.key], frame_id=j.frame_id)) for j in jobs if j.key in got]
    save_probes(out, probes, fingerprint)
    return probes


class PlainMeasure:
    """``measure(frames, config)`` for the registration refinement's rounds, the self-test and
    the separation check: no store; references only where given (frame id -> its reference
    frames, the separation check's), with ``config``'s executor,
    in any order. In serial mode one checker is kept over all rounds (the mesh and renderer
    are built once); call ``close`` at the end. Raises RunInterrupted after a Ctrl-C / SIGTERM
    (the main pass's frames stay stored)."""

    def __init__(self, desc: str = "pgt-check registration",
                 references: Mapping[str, tuple[Frame, ...]] | None = None) -> None:
        self._lender: CheckerLender | None = None  # serial: one checker over all rounds
        self._desc = desc
        self._refs = dict(references or {})

    def __call__(self, frames: Sequence[Frame], config: RunConfig) -> list[FrameMeasurement]:
        from pgt_check.executor import CheckerLender, iter_results, stop_on_sigint

        factory: Callable[[], Any] = functools.partial(build_frame_checker, config,
                                                       self._refs or None)
        if config.executor == "serial":
            if self._lender is None:
                self._lender = CheckerLender(factory)
                self._lender.borrow()  # built here, before the pass, as the rounds' one checker
            factory = self._lender.lend
        with stop_on_sigint() as stop:
            results = iter_results(frames, factory, config, stop=stop)
            ms = list(frame_progress(results, len(frames), self._desc))
            if stop.is_set() and len(ms) < len(frames):
                raise RunInterrupted(len(ms), len(frames), str(config.out))
        return ms

    def close(self) -> None:
        if self._lender is not None:
            self._lender.close()
            self._lender = None
