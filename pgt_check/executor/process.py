"""Process-pool executor (``--executor process``): spawned workers, each building one checker.

Worker processes are tracked with ``multiprocessing.active_children()`` (public API) so their
exit codes can be read after a crash, when the pool has already cleared its own table.
"""

from __future__ import annotations

import collections
import concurrent.futures as cf
import logging
import multiprocessing
import os
import signal
import threading
import time
from collections.abc import Iterable, Iterator
from typing import Any

from pgt_check.config import RunConfig
from pgt_check.executor.common import (
    INFLIGHT_PER_WORKER,
    CheckerFactory,
    CheckerSetupError,
    ExecutorStats,
    Task,
    checker_setup_error,
    close_checker,
    default_workers,
    fill,
    internal_error,
    note_stop,
    quiet_sigterm,
    worker_crashed,
)
from pgt_check.measure.record import FrameMeasurement
from pgt_check.types import Frame

logger = logging.getLogger(__name__)

_WORKER_CHECKER: Any = None
_WORKER_SETUP_ERROR: CheckerSetupError | None = None
_EXIT_WAIT_S = 5.0  # longest wait for dead workers' exit codes after a crash


def _watch_parent() -> None:
    """Exit this worker when its parent dies (a SIGKILLed run must not leave orphans)."""
    from multiprocessing.connection import wait

    parent = multiprocessing.parent_process()
    if parent is None:
        return

    def watch() -> None:
        wait([parent.sentinel])
        os._exit(1)

    threading.Thread(target=watch, name="pgt-check-parent-watch", daemon=True).start()


def _init_worker(checker_factory: CheckerFactory) -> None:
    """Pool initializer: ignore Ctrl-C (the parent handles it), build the checker once. SIGTERM
    (the pool stopping the survivors after a worker died, a CI cancel of the process group)
    ends the worker quietly, without a native library's crash dump (``quiet_sigterm``)."""
    global _WORKER_CHECKER, _WORKER_SETUP_ERROR
    from multiprocessing.util import Finalize

    signal.signal(signal.SIGINT, signal.SIG_IGN)
    _watch_parent()
    try:
        _WORKER_CHECKER = checker_factory()
    except Exception as err:  # reported by the first task, which ends the run
        _WORKER_SETUP_ERROR = checker_setup_error(err)
        return
    finally:
        quiet_sigterm()  # after the factory, which may have imported pycolmap
    Finalize(None, close_checker, args=(_WORKER_CHECKER,), exitpriority=10)


def _measure_in_worker(frame: Frame) -> FrameMeasurement:
    if _WORKER_SETUP_ERROR is not None:
        raise _WORKER_SETUP_ERROR
    return _WORKER_CHECKER.measure(frame)


def _exit_codes(procs: Iterable[Any]) -> list[int]:
    """Exit codes of dead worker processes. The pool SIGTERMs its other workers once one has
    died; those are left out."""
    codes = set()
    deadline = time.monotonic() + _EXIT_WAIT_S
    for p in procs:
        # The pool's manager thread reaps dead workers too: between its waitpid and its storing
        # the status, ours sees neither a live child nor a code. Poll until one appears.
        while p.exitcode is None and time.monotonic() < deadline:
            p.join(timeout=0.1)
        if p.exitcode not in (None, 0):
            codes.add(p.exitcode)
    return sorted(codes - {-signal.SIGTERM} or codes)


def _describe_exit(codes: list[int]) -> str:
    parts = []
    for c in codes:
        if c < 0:
            try:
                parts.append(f"killed by {signal.Signals(-c).name}")
            except ValueError:
                parts.append(f"killed by signal {-c}")
        else:
            parts.append(f"exit code {c}")
    return ", ".join(parts) if parts else "unknown exit status"


class _ProcessRun:
    """State of one process-pool run: the pool, frames in flight, frames to retry alone."""

    def __init__(
        self,
        frames: Iterable[Frame],
        checker_factory: CheckerFactory,
        config: RunConfig,
        stop: threading.Event,
        stats: ExecutorStats,
    ) -> None:
        self.factory, self.config, self.stop, self.stats = checker_factory, config, stop, stats
        self.workers = config.workers or default_workers()
        stats.workers = self.workers
        self.max_inflight = max(2, INFLIGHT_PER_WORKER * self.workers)
        self.source = iter(frames)
        self.exhausted = False
        self.retry: collections.deque[Task] = collections.deque()
        self.inflight: dict[cf.Future, Task] = {}
        self.procs: set[Any] = set()
        self.pool = self._new_pool()

    def _new_pool(self) -> cf.ProcessPoolExecutor:
        return cf.ProcessPoolExecutor(
            max_workers=self.workers,
            mp_context=multiprocessing.get_context("spawn"),
            initializer=_init_worker,
            initargs=(self.factory,),
        )

    def kill_pool(self) -> None:
        """Stop the pool now: cancel queued work and kill its workers (they may be hung)."""
        procs = set(self.procs) | set(multiprocessing.active_children())
        self.pool.shutdown(wait=False, cancel_futures=True)
        for p in procs:
            if p.is_alive():
                p.kill()
        for p in procs:
            p.join(timeout=5)
        self.procs.clear()

    def submit(self, task: Task) -> bool:
        from concurrent.futures.process import BrokenProcessPool

        try:
            fut = self.pool.submit(_measure_in_worker, task.frame)
        except BrokenProcessPool:
            self.retry.appendleft(task)
            return False
        self.inflight[fut] = task
        self.procs.update(multiprocessing.active_children())
        self.stats.submitted += 1
        return True

    def outcome(self, fut: cf.Future, task: Task, crashed: list[Task]) -> FrameMeasurement | None:
        """Measurement of a finished future, or None (crashed -> ``crashed``; cancelled)."""
        from concurrent.futures.process import BrokenProcessPool

        if fut.cancelled():
            return None
        err = fut.exception()
        if err is None:
            return fut.result()
        if isinstance(err, BrokenProcessPool):
            crashed.append(task)
            return None
        if isinstance(err, CheckerSetupError) or self.config.fail_fast:
            raise err
        if self.stop.is_set():
            return None
        return internal_error(task.frame, err)

    def collect(self, futures: Iterable[cf.Future], crashed: list[Task]) -> list[FrameMeasurement]:
        out = []
        for fut in list(futures):
            m = self.outcome(fut, self.inflight.pop(fut), crashed)
            if m is not None:
                out.append(m)
        return out

    def after_crash(self, crashed: list[Task]) -> FrameMeasurement | None:
        """Bookkeeping after the pool broke; a frame that crashed too often is returned."""
        how = _describe_exit(_exit_codes(self.procs))
        self.kill_pool()
        self.stats.worker_crashes += 1
        out = None
        if self.stop.is_set():
            logger.info("a worker died after the interrupt (%s); not retried", how)
        elif len(crashed) == 1:
            task = crashed[0]
            task.crashes += 1
            if task.crashes > self.config.retries:
                if self.config.fail_fast:
                    raise RuntimeError(f"frame {task.frame.frame_id}: worker died ({how})")
                self.stats.crashed_frames.append(task.frame.frame_id)
                out = worker_crashed(task, how)
            else:
                logger.warning("frame %s: its worker died (%s); retrying", task.frame.frame_id, how)
                self.retry.appendleft(task)
        else:
            logger.warning(
                "a worker died (%s) with %d frames in flight; re-running them one at "
                "a time to find the cause",
                how,
                len(crashed),
            )
            self.retry.extend(crashed)
        if not self.stop.is_set():
            self.pool = self._new_pool()
        return out

    def results(self) -> Iterator[FrameMeasurement]:
        noted = [False]
        while True:
            self.exhausted = fill(
                self.stop,
                self.inflight,
                self.retry,
                self.source,
                self.exhausted,
                self.max_inflight,
                self.submit,
            )
            note_stop(self.stop, noted, len(self.inflight))
            if not self.inflight:
                if self.stop.is_set() or (self.exhausted and not self.retry):
                    break
                if self.retry:  # submit failed on a broken pool: rebuild
                    self.kill_pool()
                    self.pool = self._new_pool()
                continue
            done, _ = cf.wait(self.inflight, timeout=1.0, return_when=cf.FIRST_COMPLETED)
            crashed: list[Task] = []
            yield from self.collect(done, crashed)
            if not crashed:
                continue
            # the pool is broken: every other frame in flight fails too (or just finished)
            cf.wait(self.inflight, timeout=60)
            yield from self.collect(self.inflight, crashed)
            failed = self.after_crash(crashed)
            if failed is not None:
                yield failed


def iter_process(
    frames: Iterable[Frame],
    checker_factory: CheckerFactory,
    config: RunConfig,
    stop: threading.Event,
    stats: ExecutorStats,
) -> Iterator[FrameMeasurement]:
    run = _ProcessRun(frames, checker_factory, config, stop, stats)
    logger.info(
        "process pool: %d workers (spawn), up to %d frames in flight", run.workers, run.max_inflight
    )
    clean_exit = False
    try:
        for m in run.results():
            stats.yielded += 1
            yield m
        stats.stopped = stop.is_set()
        clean_exit = True
    finally:
        if clean_exit:
            run.pool.shutdown(wait=True, cancel_futures=True)
        else:  # an exception or the consumer stopped iterating: do not wait for hung frames
            run.kill_pool()
