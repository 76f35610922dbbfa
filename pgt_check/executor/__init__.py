"""Executors: spread frames over in-process, process-pool or Dask workers and stream results back.

The unit of work is ``checker.measure(frame) -> FrameMeasurement`` where ``checker =
checker_factory()`` is built **once per worker** (process, or thread of a Dask worker) and kept
for the whole run: the factory is a picklable callable (a module-level class or
``functools.partial``), so GL contexts and models are created inside the worker that uses them
(``spawn``; see docs/renderer.md). :func:`iter_results` yields measurements as frames finish, in
any order; at most ``INFLIGHT_PER_WORKER * workers`` frames are submitted and not yet returned,
so memory does not depend on the number of frames as long as ``frames`` is an iterator.

Failures (each becomes a measurement built by ``pgt_check.measure.failed_measurement``):

* ``measure`` raising: ``internal_error`` (re-raised with ``fail_fast``).
* the checker factory raising in a worker: :class:`CheckerSetupError`, ends the run.
* a worker process dying (segfault, ``os._exit``, OOM kill): the frame is run again up to
  ``retries`` times, then becomes ``worker_crashed`` with the error. The process pool does not
  say which of its frames killed it, so after a crash the frames that were in flight are re-run
  one at a time; only a crash of a frame running alone counts against it. Dask does the same
  bookkeeping itself (``distributed.scheduler.allowed-failures``; set to ``retries`` for the
  LocalCluster started here, the scheduler's own setting for ``--scheduler``).

Stopping: pass a ``threading.Event`` as ``stop`` (see :func:`stop_on_sigint`). Once it is set
no frame is submitted; frames in flight finish and are yielded, failures after the stop are
dropped (their frames count as not done), and the generator returns.
"""

from __future__ import annotations

import threading
from collections.abc import Iterable, Iterator

from pgt_check.config import RunConfig
from pgt_check.executor.common import (
    INFLIGHT_PER_WORKER,
    Checker,
    CheckerFactory,
    CheckerLender,
    CheckerSetupError,
    ExecutorStats,
    Task,
    build_checker,
    close_checker,
    default_workers,
    internal_error,
    note_stop,
    stop_on_sigint,
)
from pgt_check.measure.record import FrameMeasurement
from pgt_check.types import Frame

__all__ = [
    "INFLIGHT_PER_WORKER",
    "Checker",
    "CheckerFactory",
    "CheckerLender",
    "CheckerSetupError",
    "ExecutorStats",
    "Task",
    "default_workers",
    "iter_results",
    "stop_on_sigint",
]


def iter_results(
    frames: Iterable[Frame],
    checker_factory: CheckerFactory,
    config: RunConfig,
    *,
    stop: threading.Event | None = None,
    stats: ExecutorStats | None = None,
) -> Iterator[FrameMeasurement]:
    """Measure ``frames`` with ``config.executor`` and yield one measurement per frame as it
    finishes (not in the order of ``frames``). Uses ``config.executor``, ``workers``,
    ``scheduler``, ``retries`` and ``fail_fast``."""
    stop = stop if stop is not None else threading.Event()
    stats = stats if stats is not None else ExecutorStats()
    stats.executor = config.executor
    if config.executor == "serial":
        return _iter_serial(frames, checker_factory, config, stop, stats)
    if config.executor == "process":
        from pgt_check.executor.process import iter_process

        return iter_process(frames, checker_factory, config, stop, stats)
    if config.executor == "dask":
        from pgt_check.executor.dask import iter_dask

        return iter_dask(frames, checker_factory, config, stop, stats)
    raise ValueError(f"unknown executor {config.executor!r} (allowed: serial, process, dask)")


def _iter_serial(
    frames: Iterable[Frame],
    checker_factory: CheckerFactory,
    config: RunConfig,
    stop: threading.Event,
    stats: ExecutorStats,
) -> Iterator[FrameMeasurement]:
    stats.workers = 1
    checker = build_checker(checker_factory)
    noted = [False]
    try:
        for frame in frames:
            if stop.is_set():
                break
            stats.submitted += 1
            try:
                m = checker.measure(frame)
            except Exception as err:
                if config.fail_fast:
                    raise
                m = internal_error(frame, err)
            stats.yielded += 1
            yield m
        note_stop(stop, noted, 0)
        stats.stopped = stop.is_set()
    finally:
        close_checker(checker)
