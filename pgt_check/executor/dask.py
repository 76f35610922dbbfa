"""Dask executor (``--executor dask``): a LocalCluster, or a running scheduler (``--scheduler``)."""

from __future__ import annotations

import collections
import logging
import threading
import uuid
from collections.abc import Callable, Iterable, Iterator
from typing import Any

from pgt_check.config import RunConfig
from pgt_check.executor.common import (
    INFLIGHT_PER_WORKER,
    CheckerFactory,
    CheckerSetupError,
    ExecutorStats,
    Task,
    build_checker,
    close_checker,
    default_workers,
    fill,
    internal_error,
    note_stop,
    worker_crashed,
)
from pgt_check.measure.record import FrameMeasurement
from pgt_check.types import Frame

logger = logging.getLogger(__name__)

_DASK_LOCAL = threading.local()


def _dask_measure(token: str, checker_factory: CheckerFactory, frame: Frame) -> FrameMeasurement:
    """Task body: one checker per worker thread and run token (GL contexts are per thread).

    The checker of a run stays cached in its thread until the next run replaces it or the
    worker stops (workers of a long-lived cluster keep one mesh per thread meanwhile).
    """
    cached = getattr(_DASK_LOCAL, "checker", None)
    if cached is None or cached[0] != token:
        if cached is not None:
            close_checker(cached[1])
        _DASK_LOCAL.checker = None
        _DASK_LOCAL.checker = (token, build_checker(checker_factory))
    return _DASK_LOCAL.checker[1].measure(frame)


def _dask_client(config: RunConfig) -> tuple[Any, Any]:
    try:
        import dask
        from distributed import Client, LocalCluster
    except ImportError as err:
        from pgt_check.errors import MissingExtraError

        raise MissingExtraError("distributed", "distributed") from err
    if config.scheduler:
        logger.info("connecting to the Dask scheduler at %s", config.scheduler)
        try:
            return Client(config.scheduler, timeout="30s"), None
        except OSError as err:
            from pgt_check.errors import InputError

            raise InputError(
                f"cannot reach the Dask scheduler at {config.scheduler}: {err}"
            ) from err
    workers = config.workers or default_workers()
    settings = {
        # a dead worker fails its tasks at once; iter_results finds the culprit and retries
        "distributed.scheduler.allowed-failures": 0,
        "distributed.worker.multiprocessing-method": "spawn",
    }
    with dask.config.set(settings):
        cluster = LocalCluster(
            n_workers=workers,
            threads_per_worker=1,
            processes=True,
            dashboard_address=None,
            silence_logs=logging.ERROR,
        )
        client = Client(cluster)
    logger.info("Dask LocalCluster: %d workers x 1 thread", workers)
    return client, cluster


class _DaskRun:
    """State of one Dask run: the client, frames in flight, frames to retry alone."""

    def __init__(
        self,
        client: Any,
        checker_factory: CheckerFactory,
        config: RunConfig,
        stop: threading.Event,
        stats: ExecutorStats,
        as_completed: Callable[[], Any],
        killed: type[BaseException],
    ) -> None:
        """``as_completed`` / ``killed``: distributed's, imported before connecting."""
        self.client, self.factory, self.config, self.stop, self.stats = (
            client, checker_factory, config, stop, stats,
        )  # fmt: skip
        self.as_completed, self.killed = as_completed, killed
        self.token = uuid.uuid4().hex[:12]
        self.inflight: dict[Any, Task] = {}
        self.retry: collections.deque[Task] = collections.deque()
        self.source: Iterator[Frame] = iter(())
        self.exhausted = False
        self.max_inflight = 2
        self.ac: Any = None

    def submit(self, task: Task) -> bool:
        """Send one frame to the cluster (never refused)."""
        fut = self.client.submit(
            _dask_measure,
            self.token,
            self.factory,
            task.frame,
            key=f"pgt-check-{self.token}-{self.stats.submitted}",
            pure=False,
        )
        self.inflight[fut] = task
        self.stats.submitted += 1
        self.ac.add(fut)
        return True

    def refill(self) -> None:
        """Submit frames under the policy both pools share (``fill``)."""
        self.exhausted = fill(
            self.stop,
            self.inflight,
            self.retry,
            self.source,
            self.exhausted,
            self.max_inflight,
            self.submit,
        )

    def outcome(self, fut: Any, task: Task) -> FrameMeasurement | None:
        """Measurement of a completed future, or None (cancelled, stopping, re-queued)."""
        if fut.status == "finished":
            return fut.result()
        if fut.status == "cancelled" or self.stop.is_set():
            return None
        if fut.status != "error":
            # "lost" (or "pending" again): the frame finished, but the worker holding its result
            # died before it was fetched; not a failure of the frame, so it is measured again
            # (a released future is not recomputed for us, and as_completed yields it only once)
            logger.warning(
                "frame %s: its result was lost with a worker (%s); measuring it again",
                task.frame.frame_id,
                fut.status,
            )
            self.retry.append(task)
            return None
        err = fut.exception()
        if isinstance(err, CheckerSetupError):
            raise err
        if isinstance(err, self.killed):
            return _dask_crash(task, err, self.retry, self.config, self.stats)
        if self.config.fail_fast:
            raise err
        return internal_error(task.frame, err)

    def results(self, frames: Iterable[Frame]) -> Iterator[FrameMeasurement]:
        """The frames' measurements as they complete."""
        nthreads = sum(self.client.nthreads().values()) or 1
        self.stats.workers = nthreads
        self.max_inflight = max(2, INFLIGHT_PER_WORKER * nthreads)
        self.source = iter(frames)
        self.ac = self.as_completed()
        logger.info(
            "Dask: %d worker threads, up to %d frames in flight", nthreads, self.max_inflight
        )
        noted = [False]
        self.refill()
        for fut in self.ac:
            rec = self.outcome(fut, self.inflight.pop(fut))
            fut.release()
            if rec is not None:
                self.stats.yielded += 1
                yield rec
            note_stop(self.stop, noted, len(self.inflight))
            self.refill()


def iter_dask(
    frames: Iterable[Frame],
    checker_factory: CheckerFactory,
    config: RunConfig,
    stop: threading.Event,
    stats: ExecutorStats,
) -> Iterator[FrameMeasurement]:
    """Measure ``frames`` on a Dask cluster (``_dask_client``); yields as frames finish."""
    from distributed import as_completed
    from distributed.scheduler import KilledWorker

    client, cluster = _dask_client(config)
    run = _DaskRun(client, checker_factory, config, stop, stats, as_completed, KilledWorker)
    try:
        yield from run.results(frames)
        stats.stopped = stop.is_set()
    finally:
        if run.inflight:
            client.cancel(list(run.inflight))
        client.close()
        if cluster is not None:
            cluster.close()


def _dask_crash(
    task: Task,
    err: BaseException,
    retry: collections.deque[Task],
    config: RunConfig,
    stats: ExecutorStats,
) -> FrameMeasurement | None:
    """A frame's task died with its worker (after the scheduler's own allowed-failures)."""
    fid = task.frame.frame_id
    stats.worker_crashes += 1
    if not task.isolated:  # other frames were running: it may be innocent
        logger.warning("frame %s: a worker died while it ran with others; re-running it alone", fid)
        retry.append(task)
        return None
    task.crashes += 1
    if task.crashes <= config.retries:
        logger.warning("frame %s: its worker died; retrying", fid)
        retry.appendleft(task)
        return None
    if config.fail_fast:
        raise RuntimeError(f"frame {fid}: worker died: {err}")
    stats.crashed_frames.append(fid)
    return worker_crashed(task, f"{type(err).__name__}: {err}")
