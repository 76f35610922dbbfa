"""Dask executor (``--executor dask``): a LocalCluster, or a running scheduler (``--scheduler``)."""

from __future__ import annotations

import collections
import logging
import threading
import uuid
from collections.abc import Iterable, Iterator
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


def iter_dask(
    frames: Iterable[Frame],
    checker_factory: CheckerFactory,
    config: RunConfig,
    stop: threading.Event,
    stats: ExecutorStats,
) -> Iterator[FrameMeasurement]:
    from distributed import as_completed
    from distributed.scheduler import KilledWorker

    client, cluster = _dask_client(config)
    token = uuid.uuid4().hex[:12]
    inflight: dict[Any, Task] = {}
    retry: collections.deque[Task] = collections.deque()
    noted = [False]
    try:
        nthreads = sum(client.nthreads().values()) or 1
        stats.workers = nthreads
        max_inflight = max(2, INFLIGHT_PER_WORKER * nthreads)
        source = iter(frames)
        exhausted = False
        ac = as_completed()
        logger.info("Dask: %d worker threads, up to %d frames in flight", nthreads, max_inflight)

        def submit(task: Task) -> bool:
            fut = client.submit(
                _dask_measure,
                token,
                checker_factory,
                task.frame,
                key=f"pgt-check-{token}-{stats.submitted}",
                pure=False,
            )
            inflight[fut] = task
            stats.submitted += 1
            ac.add(fut)
            return True

        def refill() -> None:
            nonlocal exhausted
            exhausted = fill(stop, inflight, retry, source, exhausted, max_inflight, submit)

        refill()
        for fut in ac:
            task = inflight.pop(fut)
            frame = task.frame
            rec: FrameMeasurement | None = None
            if fut.status == "finished":
                rec = fut.result()
            elif fut.status != "cancelled" and not stop.is_set():
                err = fut.exception()
                if isinstance(err, CheckerSetupError):
                    raise err
                if isinstance(err, KilledWorker):
                    rec = _dask_crash(task, err, retry, config, stats)
                else:
                    if config.fail_fast:
                        raise err
                    rec = internal_error(frame, err)
            fut.release()
            if rec is not None:
                stats.yielded += 1
                yield rec
            note_stop(stop, noted, len(inflight))
            refill()
        stats.stopped = stop.is_set()
    finally:
        if inflight:
            client.cancel(list(inflight))
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
