"""Composes a run: read -> measure every frame (executor + store) -> verdicts -> corrections
-> outputs.

Stage 1 (``pgt_check.measure``) produces one ``FrameMeasurement`` per frame (raw, enhanced and
geometric-edge paths) and never raises for one bad frame; measurements stream into
``out/records.jsonl`` (append-only, resumable). Stage 2 (``pgt_check.verdict``) runs the
run-level checks and applies thresholds; stage 3 (``pgt_check.correct``) refines a failed
registration check's estimate and corrects the chosen frames' poses; stage 4
(``pgt_check.report``) writes frames.csv, summary.json, junit.xml and report.html from the rows.
"""

from __future__ import annotations

import functools
import logging
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from pgt_check.config import RunConfig
from pgt_check.content_hash import mesh_content_hash
from pgt_check.errors import InputError, RunInterrupted
from pgt_check.io import check_frame_ids
from pgt_check.measure import (
    FrameImages,
    FrameMeasurement,
    OldRecordError,
    build_frame_checker,
    pick_references,
)
from pgt_check.progress import frame_progress, log_progress
from pgt_check.stages.inputs import (  # re-exported: tests and callers patch / import them here
    check_side_inputs,
    content_hash,
    frame_input_keys,
    images_outside_dataset,
    input_file_hashes,
    load_trajectory,
    measurement_fingerprint,
    preflight,
)
from pgt_check.stages.remeasure import (
    PlainMeasure,
    correct_stage,
    reference_stage,
    self_test_stage,
    separation_stage,
)
from pgt_check.stages.scene_check import resolve_enhancer_output
from pgt_check.threads import run_threads
from pgt_check.types import Frame, Trajectory
from pgt_check.verdict import RunResult, judge_run
from pgt_check.verdict.outcome import RunOutcome, judge_outcome

if TYPE_CHECKING:
    from pgt_check.report.assets import PanelWriter

logger = logging.getLogger(__name__)

__all__ = [
    "PreparedRun", "RunInterrupted", "check_frames", "content_hash", "frame_input_keys",
    "images_outside_dataset", "load_trajectory", "log_progress", "measurement_fingerprint",
    "PlainMeasure", "panel_writer", "preflight", "run", "run_trajectory", "stored_measurements",
    "write_report_assets",
]


def run(config: RunConfig) -> RunOutcome:
    """Check every frame of the configured trajectory and write the outputs to ``config.out``.

    Returns the run's outcome (its gate, statistics, accuracy and corrected result; written as
    summary.json and the other outputs). Raises InputError for user errors
    (SetupError when the chosen mesh / renderer / matcher / enhancer cannot be built, found
    before any frame is measured) and RunInterrupted after a Ctrl-C or SIGTERM (the frames done
    so far are kept for ``--resume``).
    """
    t0 = time.perf_counter()
    traj = load_trajectory(config)
    return run_trajectory(traj, config, t0=t0)


def run_trajectory(
    traj: Trajectory, config: RunConfig, *, t0: float | None = None
) -> RunOutcome:
    """``run`` on an already read trajectory (the Python API passes in-memory ones): the one
    path from frames to outputs, so the CLI and the API key stored measurements alike (the
    mesh's content hash with its side files in the fingerprint, ``frame_input_keys`` per
    record): a moved pose, a replaced photo or a changed mesh is never reused from ``out``.
    OpenCV's and BLAS's threads are ``config.threads`` until it returns."""
    with run_threads(config.threads):
        return _run_trajectory(traj, config, t0)


def _run_trajectory(traj: Trajectory, config: RunConfig, t0: float | None) -> RunOutcome:
    t0 = time.perf_counter() if t0 is None else t0
    check_frame_ids(traj.frames, traj.source)  # in-memory trajectories of the API too
    frames = list(traj.frames)
    if config.limit is not None:
        frames = frames[: config.limit]
    logger.info("checking %d frames of %s (%s)", len(frames), traj.source or "a trajectory",
                traj.format or "in-memory")
    check_side_inputs(config, frames)
    references = pick_references(traj, frames, config)
    checker = preflight(config, references)  # loads the mesh: its side files are known here
    try:
        # MaRINeR's decoder or its matching-only base, from the scene's own photos: a setting
        # of the whole run, so it is decided before the fingerprint
        config = resolve_enhancer_output(config, frames, references, checker)
        t_hash = time.perf_counter()
        inputs = {"mesh": mesh_content_hash(config.input.mesh, _side_files(checker))}
        image_hashes: dict[str, str] = {}
        keys = frame_input_keys(frames, references, image_hashes)
        prepared = PreparedRun.of(
            frames, config, input_keys=keys, inputs=inputs,
            trajectory=traj, trajectory_format=traj.format or "in-memory",
            outside_dataset=images_outside_dataset(config, frames) if config.input.trajectory
            else (),
            input_files=input_file_hashes(config, _side_files(checker), image_hashes,
                                          traj.metadata),
        )
        logger.info("hashed the inputs in %.2f s", time.perf_counter() - t_hash)
        sink = panel_writer(config, prepared.fingerprint)
        if sink is not None:
            checker.panel_sink = sink
    except BaseException:
        checker.close()
        raise
    from pgt_check.executor import CheckerLender

    build = functools.partial(build_frame_checker, config, references, panel_sink=sink)
    # the serial executor's main pass measures with the checker built here
    lender = CheckerLender(build, checker if config.executor == "serial" else None)
    if config.executor != "serial":
        checker.close()
    outside = prepared.outside_dataset
    if outside:
        logger.warning("%d image paths point outside the dataset folder (e.g. %r): they were "
                       "read and their thumbnails may appear in this report", len(outside),
                       outside[0])
    try:
        return check_frames(prepared, config, lender.hand_over, t0=t0)
    finally:
        lender.close()  # the checker built here, where no pass took it


def _side_files(checker: Any) -> tuple[str, ...]:
    """The files the checker's mesh loader read besides the mesh file (``MeshData.side_files``;
    none for a checker without a loaded mesh)."""
    mesh = getattr(checker, "_mesh", None) or getattr(checker, "mesh", None)
    return tuple(getattr(mesh, "side_files", ()) or ())


def panel_writer(config: RunConfig, fingerprint: str) -> PanelWriter | None:
    """The checker's panel sink: report panels of likely detail frames from the main pass."""
    if config.report_details <= 0:
        return None
    from pgt_check.report.assets import PanelWriter

    return PanelWriter(config.out, fingerprint, config.verdict)


def stored_measurements(records: Sequence[dict[str, Any]]) -> list[FrameMeasurement]:
    """Decode stored records; a record of another layout is an InputError naming the fix."""
    try:
        return [FrameMeasurement.from_json(r) for r in records]
    except OldRecordError as err:
        raise InputError(str(err)) from err


@dataclass(frozen=True)
class PreparedRun:
    """What a run knows before it measures: its frames (in order) and trajectory, each frame's
    input key (``frame_input_keys``: a stored record counts as done only if it carries the same
    key), the run-wide content hashes (``{"mesh": ...}``) and the measurement fingerprint
    computed from them once, and what summary.json says of the inputs (the trajectory's
    format, image paths outside the dataset folder)."""

    frames: tuple[Frame, ...]
    trajectory: Trajectory
    input_keys: Mapping[str, str]
    inputs: Mapping[str, str]
    fingerprint: str
    trajectory_format: str = "in-memory"
    outside_dataset: tuple[str, ...] = ()
    #: absolute path -> content hash of every input file (``stages.inputs.input_file_hashes``: run.json
    #: keeps them for ``pgt-check report``, which says which input changed since)
    input_files: Mapping[str, str] = field(default_factory=dict)

    @classmethod
    def of(cls, frames: Sequence[Frame], config: RunConfig, *, input_keys: Mapping[str, str],
           inputs: Mapping[str, str], trajectory: Trajectory | None = None,
           trajectory_format: str = "in-memory",
           outside_dataset: Sequence[str] = (),
           input_files: Mapping[str, str] | None = None) -> PreparedRun:
        """Both ``input_keys`` and ``inputs`` are required: a stored measurement is reused
        only on matching content."""
        frames = tuple(frames)
        return cls(frames, trajectory if trajectory is not None else Trajectory(frames),
                   dict(input_keys), dict(inputs), measurement_fingerprint(config, dict(inputs)),
                   trajectory_format, tuple(outside_dataset), dict(input_files or {}))

    @property
    def ids(self) -> list[str]:
        return [f.frame_id for f in self.frames]


def check_frames(
    prepared: PreparedRun,
    config: RunConfig,
    checker_factory: Callable[[], Any],
    *,
    t0: float | None = None,
) -> RunOutcome:
    """Measure the prepared run's frames (skipping those already in the store with the same
    fingerprint and input key), judge and correct them, then write the outputs; return the
    run's outcome.

    Measurements stream from the executor into ``out/records.jsonl`` as frames finish; the
    outputs are built from the store in ``frames`` order, so a resumed run writes the same
    frames.csv as an uninterrupted one (timing columns aside). The store's lock is held until
    the output set is complete (``outputs.complete.json``): a second run into the same ``out``
    cannot write between the measurements and the outputs built from them.
    """
    with run_threads(config.threads), _open_store(config, prepared) as store:
        return _check_frames_locked(store, prepared, config, checker_factory, t0)


def _check_frames_locked(
    store: Any,
    prepared: PreparedRun,
    config: RunConfig,
    checker_factory: Callable[[], Any],
    t0: float | None,
) -> RunOutcome:
    """``check_frames`` with the store open (and locked) by the caller."""
    from pgt_check.executor import ExecutorStats
    from pgt_check.report.outputs import ExecutorSummary, RunFacts, write_outcome

    t0 = time.perf_counter() if t0 is None else t0
    out = Path(config.out)
    stats = ExecutorStats()
    measurements, n_reused = _measure_into_store(store, prepared, config, checker_factory, stats)
    measurements = _reference_pass(store, prepared, config, measurements)
    traj = prepared.trajectory
    # each path's separating power on this run: frames moved by a known amount, measured again
    probes = separation_stage(traj, measurements, config, prepared.fingerprint)
    judged = judge_run(measurements, config, probes)
    result = correct_stage(traj, measurements, judged, config, checker_factory)
    if config.self_test > 0:  # the stated detection limits tested (``verdict.self_test``)
        result = self_test_stage(traj, result, config)
    outcome = judge_outcome(result, config)  # the gate, decided on the corrected run
    assets = write_report_assets(prepared.frames, result, config, checker_factory,
                                 prepared.fingerprint)
    shadings = sorted({str(m.shading) for m in measurements if m.shading})
    facts = RunFacts(
        trajectory_format=prepared.trajectory_format,
        shading=shadings[0] if len(shadings) == 1 else (shadings or None),
        executor=ExecutorSummary(config.executor, stats.workers, stats.yielded, n_reused,
                                 stats.worker_crashes),
        outside_dataset=prepared.outside_dataset,
        wall_time_s=time.perf_counter() - t0,
    )
    write_outcome(out, outcome, config, facts, assets=assets)
    return outcome


def _reference_pass(
    store: Any, prepared: PreparedRun, config: RunConfig, measurements: list[FrameMeasurement]
) -> list[FrameMeasurement]:
    """Frames whose enhanced path leaned on a reference whose own absolute evidence did not
    pass are measured again with references among the frames whose evidence did
    (``enhance.refs.verified_references``, on a first judgement of the main pass): a wrong
    neighbour must not decide, or starve, a correct frame. Their records are appended to the
    store (the latest one counts, so ``pgt-check report`` judges them too; ``--resume``
    measures them again from the first choice)."""
    refs, got = reference_stage(prepared.trajectory, prepared.frames, measurements, config)
    if not refs:
        return measurements
    frames = [f for f in prepared.frames if f.frame_id in refs]
    keys = frame_input_keys(frames, refs)
    for f in frames:
        if f.frame_id in got:
            store.append_measurement(got[f.frame_id].to_json(), keys.get(f.frame_id, ""))
    return [got.get(m.frame_id, m) for m in measurements]


def _open_store(config: RunConfig, prepared: PreparedRun) -> Any:
    """The run's ``RecordStore`` context manager; an unusable ``--out`` is an InputError."""
    from pgt_check.output_layout import OUTPUTS
    from pgt_check.store import RecordStore

    out = Path(config.out)
    settings = config.measurement_settings()
    if prepared.inputs:
        settings["inputs"] = dict(prepared.inputs)
    try:
        return RecordStore.open(
            out,
            prepared.fingerprint,
            resume=config.resume,
            overwrite=config.overwrite,
            settings=settings,
            frame_ids=prepared.ids,
            outputs=OUTPUTS.marked_files(),  # refused where one is a file pgt-check did not write
            input_files=prepared.input_files,
        )
    except OSError as err:
        raise InputError(
            f"--out {out}: cannot use it as the output directory "
            f"({err.strerror or type(err).__name__}{': ' + str(err.filename) if err.filename else ''})"
        ) from err


def _measure_into_store(
    store: Any,
    prepared: PreparedRun,
    config: RunConfig,
    checker_factory: Callable[[], Any],
    stats: Any,
) -> tuple[list[FrameMeasurement], int]:
    """Measure the frames not yet in ``store`` (streaming each record into it) and return all
    measurements in trajectory order plus the number of frames reused from the store. Raises
    RunInterrupted when a Ctrl-C / SIGTERM stopped the run before every frame was done."""
    from pgt_check.executor import iter_results, stop_on_sigint
    from pgt_check.report.outputs import remove_completion_marker

    out = Path(config.out)
    frames, ids, input_keys = prepared.frames, prepared.ids, prepared.input_keys
    remove_completion_marker(out)  # the output set is incomplete from here on
    done = _done_ids(store, ids, input_keys)
    if done:
        logger.info("%d of %d frames already measured with these settings and inputs: "
                    "skipped", len(done), len(frames))
    stale = store.done_ids().intersection(ids) - done
    if stale:
        logger.info("%d frames whose inputs changed (pose, camera or image content) are "
                    "measured again", len(stale))
    todo = (f for f in frames if f.frame_id not in done)
    with stop_on_sigint() as stop:
        results = iter_results(todo, checker_factory, config, stop=stop, stats=stats)
        for m in frame_progress(results, len(frames) - len(done), "pgt-check"):
            store.append_measurement(m.to_json(), input_keys.get(m.frame_id, ""))
        interrupted = stop.is_set()
    if interrupted:
        n_done = len(_done_ids(store, ids, input_keys))
        if n_done < len(ids):
            logger.warning("interrupted: %d/%d frames done, stored in %s", n_done, len(ids), out)
            raise RunInterrupted(n_done, len(ids), str(out))
    return stored_measurements(store.records_in_order(ids)), len(done)


def _done_ids(store: Any, ids: Sequence[str], input_keys: Mapping[str, str]) -> set[str]:
    """Frames of ``ids`` whose latest current record also has the current input key."""
    latest = store.latest_records(ids)
    return {fid for fid, rec in latest.items() if rec.input_key == input_keys.get(fid)}


def write_report_assets(
    frames: Sequence[Frame],
    result: RunResult,
    config: RunConfig,
    checker_factory: Callable[[], Any],
    fingerprint: str,
) -> dict[str, dict[str, str]] | None:
    """Panels for the report's detail frames (``report.assets.report_panels``); the selected
    frames without panels from the main pass are measured again here (in this process,
    keeping their images)."""
    from pgt_check.executor import CheckerLender
    from pgt_check.report.assets import report_panels

    if config.report_details <= 0:
        return None
    by_id = {f.frame_id: f for f in frames}
    lender = CheckerLender(checker_factory)  # built on the first frame measured again

    def again(frame_id: str) -> FrameImages | None:
        """``frame_id -> FrameImages`` of a frame measured again (None for an unknown frame
        or one without a photo)."""
        if frame_id not in by_id:
            return None
        checker = lender.borrow()
        if getattr(checker, "panel_sink", None) is not None:
            checker.panel_sink = None  # panels are written for these frames only
        images = FrameImages()
        checker.measure(by_id[frame_id], keep=images)
        return None if images.photo is None else images

    try:
        return report_panels(config.out, result, config.report_details, fingerprint, again)
    finally:
        lender.close()
