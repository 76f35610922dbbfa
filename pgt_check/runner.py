"""Composes a run: read -> measure every frame (executor + store) -> verdicts -> outputs.

Stage 1 (``pgt_check.measure``) produces one ``FrameMeasurement`` per frame and never raises
for one bad frame; measurements stream into ``out/records.jsonl`` (append-only, resumable).
Stage 2 (``pgt_check.verdict``) applies thresholds; stage 3 (``pgt_check.report``) writes
frames.csv, summary.json, junit.xml and report.html from the verdict rows.
"""

from __future__ import annotations

import functools
import logging
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from pgt_check.config import RunConfig
from pgt_check.errors import InputError
from pgt_check.measure import (
    SCHEMA_VERSION,
    FrameImages,
    FrameMeasurement,
    OldRecordError,
    build_frame_checker,
    pick_references,
)
from pgt_check.types import Frame, Trajectory
from pgt_check.verdict import apply_verdicts

logger = logging.getLogger(__name__)


def load_trajectory(config: RunConfig) -> Trajectory:
    from pgt_check.io import read_trajectory

    inp = config.input
    if not inp.trajectory:
        raise InputError("no trajectory given")
    if not inp.mesh:
        raise InputError("no mesh given (--mesh)")
    if not Path(inp.mesh).is_file():
        raise InputError(f"mesh not found: {inp.mesh}")
    traj = read_trajectory(
        inp.trajectory, inp.format, images=inp.images, camera=inp.camera, sensors=inp.sensors,
        dataparser_transforms=inp.dataparser_transforms,
    )
    if len(traj) == 0:
        raise InputError(f"{inp.trajectory}: no frames with both a pose and an image")
    return traj


def _progress(iterable, total: int, desc: str):
    try:
        from tqdm import tqdm
    except ImportError:  # pragma: no cover - tqdm is a core dependency
        return iterable
    return tqdm(iterable, total=total, desc=desc, unit="frame", disable=None)


def run(config: RunConfig) -> dict[str, Any]:
    """Check every frame of the configured trajectory and write the outputs to ``config.out``.

    Returns the summary (also written as summary.json). Raises InputError for user errors and
    RunInterrupted after a Ctrl-C (the frames done so far are kept for ``--resume``).
    """
    t0 = time.perf_counter()
    traj = load_trajectory(config)
    frames = list(traj.frames)
    if config.limit is not None:
        frames = frames[: config.limit]
    logger.info("checking %d frames of %s (%s)", len(frames), traj.source, traj.format)
    references = pick_references(traj, frames, config)
    return check_frames(
        frames,
        config,
        functools.partial(build_frame_checker, config, references),
        extra={"trajectory_format": traj.format},
        t0=t0,
        trajectory=traj,
    )


class RunInterrupted(Exception):
    """The run stopped on Ctrl-C; ``done`` of ``total`` frames are stored in ``out``."""

    def __init__(self, done: int, total: int, out: str) -> None:
        super().__init__(f"interrupted: {done}/{total} frames done")
        self.done, self.total, self.out = done, total, out


def measurement_fingerprint(config: RunConfig) -> str:
    """Fingerprint of the stored measurements: their settings and the record layout."""
    return config.measurement_fingerprint(schema=SCHEMA_VERSION)


def stored_measurements(records: Sequence[dict[str, Any]]) -> list[FrameMeasurement]:
    """Decode stored records; a record of another layout is an InputError naming the fix."""
    try:
        return [FrameMeasurement.from_json(r) for r in records]
    except OldRecordError as err:
        raise InputError(str(err)) from err


def check_frames(
    frames: Sequence[Frame],
    config: RunConfig,
    checker_factory: Callable[[], Any],
    *,
    extra: dict[str, Any] | None = None,
    t0: float | None = None,
    trajectory: Trajectory | None = None,
) -> dict[str, Any]:
    """Measure ``frames`` (skipping those already in the store), then write the outputs.

    Measurements stream from the executor into ``out/records.jsonl`` as frames finish; the
    outputs are built from the store in ``frames`` order, so a resumed run writes the same
    frames.csv as an uninterrupted one (timing columns aside).
    """
    from pgt_check.executor import ExecutorStats, iter_results, stop_on_sigint
    from pgt_check.report.outputs import write_outputs
    from pgt_check.store import RecordStore

    t0 = time.perf_counter() if t0 is None else t0
    out = Path(config.out)
    ids = [f.frame_id for f in frames]
    stats = ExecutorStats()
    with RecordStore.open(
        out,
        measurement_fingerprint(config),
        resume=config.resume,
        overwrite=config.overwrite,
        settings=config.measurement_settings(),
        frame_ids=ids,
    ) as store:
        done = store.done_ids().intersection(ids)
        if done:
            logger.info("%d of %d frames already measured with these settings: skipped",
                        len(done), len(frames))
        todo = (f for f in frames if f.frame_id not in done)
        with stop_on_sigint() as stop:
            results = iter_results(todo, checker_factory, config, stop=stop, stats=stats)
            for m in _progress(results, len(frames) - len(done), "pgt-check"):
                store.append(m.to_json())
            interrupted = stop.is_set()
        if interrupted:
            n_done = len(store.done_ids().intersection(ids))
            if n_done < len(ids):
                logger.warning("interrupted: %d/%d frames done, stored in %s", n_done, len(ids),
                               out)
                raise RunInterrupted(n_done, len(ids), str(out))
        measurements = stored_measurements(store.records_in_order(ids))
    rows = apply_verdicts(measurements, config)
    corrections: dict[str, Any] = {}
    if config.correct.frames != "none":  # corrected poses (pgt_check.corrections)
        from pgt_check.corrections import correct_run

        traj = trajectory if trajectory is not None else Trajectory(tuple(frames))
        rows, corrections = correct_run(traj, measurements, rows, config, checker_factory, out)
    assets = write_report_assets(frames, rows, config, checker_factory)
    shadings = sorted({str(m.shading) for m in measurements if m.shading})
    summary_extra = {
        "shading": shadings[0] if len(shadings) == 1 else (shadings or None),
        "executor": {
            "kind": config.executor,
            "workers": stats.workers,
            "frames_measured": stats.yielded,
            "frames_reused": len(done),
            "worker_crashes": stats.worker_crashes,
        },
        **(extra or {}),
        **corrections,
        "wall_time_s": time.perf_counter() - t0,
    }
    return write_outputs(out, rows, config, extra=summary_extra, assets=assets)


def write_report_assets(
    frames: Sequence[Frame],
    rows: list[dict[str, Any]],
    config: RunConfig,
    checker_factory: Callable[[], Any],
) -> dict[str, dict[str, str]] | None:
    """Thumbnails for the report's detail panels: the selected frames are measured again here
    (in this process, keeping their images); other frames never keep images."""
    from pgt_check.report.assets import select_detail_frames, write_frame_assets

    if config.report_details <= 0:
        return None
    chosen = select_detail_frames(rows, max_details=config.report_details)
    if not chosen:
        return None
    by_id = {f.frame_id: f for f in frames}
    row_by_id = {r["frame_id"]: r for r in rows}
    checker = checker_factory()
    assets: dict[str, dict[str, str]] = {}
    try:
        for fid in chosen:
            images = FrameImages()
            checker.measure(by_id[fid], keep=images)
            if images.photo is None:
                continue
            assets[fid] = write_frame_assets(Path(config.out), row_by_id[fid], images)
    finally:
        checker.close()
    return assets
