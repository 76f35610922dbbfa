"""Executors: spread frames over in-process, process-pool or Dask workers and stream results back.

The unit of work is ``checker.measure(frame) -> record`` where ``checker = checker_factory()``
is built **once per worker** (process, or thread of a Dask worker) and kept for the whole run:
the factory is a picklable callable (a module-level class or ``functools.partial``), so GL
contexts and models are created inside the worker that uses them (``spawn``; see
docs/renderer.md). :func:`iter_results` yields records as frames finish, in any order; at most
``inflight_per_worker * workers`` frames are submitted and not yet returned, so memory does not
depend on the number of frames as long as ``frames`` is an iterator.

Failures:

* ``measure`` raising: ``internal_error`` record (re-raised with ``fail_fast``).
* the checker factory raising in a worker: :class:`CheckerSetupError`, ends the run.
* a worker process dying (segfault, ``os._exit``, OOM kill): the frame is run again up to
  ``retries`` times, then becomes a ``worker_crashed`` record with the error. The process pool
  does not say which of its frames killed it, so after a crash the frames that were in flight
  are re-run one at a time; only a crash of a frame running alone counts against it. Dask does
  the same bookkeeping itself (``distributed.scheduler.allowed-failures``; set to ``retries``
  for the LocalCluster started here, the scheduler's own setting for ``--scheduler``).

Stopping: pass a ``threading.Event`` as ``stop`` (see :func:`stop_on_sigint`). Once it is set
no frame is submitted; frames in flight finish and are yielded, failures after the stop are
dropped (their frames count as not done), and the generator returns.
"""

from __future__ import annotations

import collections
import concurrent.futures as cf
import contextlib
import logging
import os
import signal
import threading
import traceback
import uuid
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from typing import Any, Protocol

from pgt_check.config import RunConfig
from pgt_check.types import Frame

logger = logging.getLogger(__name__)

#: submitted-but-unfinished frames per worker (bounds memory, keeps workers busy)
INFLIGHT_PER_WORKER = 2


class Checker(Protocol):
    def measure(self, frame: Frame) -> dict[str, Any]: ...


CheckerFactory = Callable[[], Checker]
ErrorRecord = Callable[[Frame, str, str], dict[str, Any]]


class CheckerSetupError(RuntimeError):
    """Building the checker failed in a worker (bad mesh, missing GL): the run cannot go on."""


def default_error_record(frame: Frame, error: str, detail: str) -> dict[str, Any]:
    """A minimal failure record; the runner passes one with the full record schema."""
    return {"frame_id": frame.frame_id, "error": error, "error_detail": detail}


@dataclass
class ExecutorStats:
    """Counters of one :func:`iter_results` call (filled while it runs)."""

    executor: str = "serial"
    workers: int = 1
    submitted: int = 0
    yielded: int = 0
    worker_crashes: int = 0
    crashed_frames: list[str] = field(default_factory=list)
    stopped: bool = False


def default_workers() -> int:
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - not Linux
        return max(1, os.cpu_count() or 1)


@contextlib.contextmanager
def stop_on_sigint() -> Iterator[threading.Event]:
    """While active, the first SIGINT sets the yielded event; a second raises KeyboardInterrupt.

    Outside the main thread (where signal handlers cannot be installed) it only yields an event.
    """
    stop = threading.Event()
    if threading.current_thread() is not threading.main_thread():
        yield stop
        return

    def handler(signum: int, frame: Any) -> None:
        if stop.is_set():
            raise KeyboardInterrupt
        stop.set()

    previous = signal.signal(signal.SIGINT, handler)
    try:
        yield stop
    finally:
        signal.signal(signal.SIGINT, previous)


def iter_results(
    frames: Iterable[Frame],
    checker_factory: CheckerFactory,
    config: RunConfig,
    *,
    stop: threading.Event | None = None,
    error_record: ErrorRecord = default_error_record,
    stats: ExecutorStats | None = None,
) -> Iterator[dict[str, Any]]:
    """Measure ``frames`` with ``config.executor`` and yield one record per frame as it finishes.

    Order of the records is not the order of ``frames``. Uses ``config.executor``,
    ``config.workers``, ``config.scheduler``, ``config.retries`` and ``config.fail_fast``.
    """
    stop = stop if stop is not None else threading.Event()
    stats = stats if stats is not None else ExecutorStats()
    stats.executor = config.executor
    if config.executor == "serial":
        return _iter_serial(frames, checker_factory, config, stop, error_record, stats)
    if config.executor == "process":
        return _iter_process(frames, checker_factory, config, stop, error_record, stats)
    if config.executor == "dask":
        return _iter_dask(frames, checker_factory, config, stop, error_record, stats)
    raise ValueError(f"unknown executor {config.executor!r} (allowed: serial, process, dask)")


def _format_exc(err: BaseException) -> str:
    return "".join(traceback.format_exception(err))[-2000:]


def _build(checker_factory: CheckerFactory) -> Checker:
    try:
        return checker_factory()
    except Exception as err:
        raise CheckerSetupError(f"building the checker failed: {_format_exc(err)}") from err


def _close(checker: Any) -> None:
    close = getattr(checker, "close", None)
    if callable(close):
        try:
            close()
        except Exception:  # closing must not hide the run's result
            logger.exception("closing the checker failed")


def _note_stop(stop: threading.Event, noted: list[bool], inflight: int) -> None:
    if stop.is_set() and not noted[0]:
        noted[0] = True
        logger.warning(
            "interrupt: finishing %d frames in flight, then stopping (Ctrl-C again aborts now)",
            inflight,
        )


# -- serial ----------------------------------------------------------------------------------
def _iter_serial(
    frames: Iterable[Frame],
    checker_factory: CheckerFactory,
    config: RunConfig,
    stop: threading.Event,
    error_record: ErrorRecord,
    stats: ExecutorStats,
) -> Iterator[dict[str, Any]]:
    stats.workers = 1
    checker = _build(checker_factory)
    noted = [False]
    try:
        for frame in frames:
            if stop.is_set():
                break
            stats.submitted += 1
            try:
                rec = checker.measure(frame)
            except Exception as err:
                if config.fail_fast:
                    raise
                logger.error("frame %s: internal error: %s", frame.frame_id, err)
                rec = error_record(frame, "internal_error", _format_exc(err))
            stats.yielded += 1
            yield rec
        _note_stop(stop, noted, 0)
        stats.stopped = stop.is_set()
    finally:
        _close(checker)


# -- process pool ----------------------------------------------------------------------------
_WORKER_CHECKER: Any = None
_WORKER_SETUP_ERROR: str | None = None


def _watch_parent() -> None:
    """Exit this worker when its parent dies (a SIGKILLed run must not leave orphans)."""
    import multiprocessing
    from multiprocessing.connection import wait

    parent = multiprocessing.parent_process()
    if parent is None:
        return

    def watch() -> None:
        wait([parent.sentinel])
        os._exit(1)

    threading.Thread(target=watch, name="pgt-check-parent-watch", daemon=True).start()


def _init_process_worker(checker_factory: CheckerFactory) -> None:
    """Pool initializer: ignore Ctrl-C (the parent handles it), build the checker once."""
    global _WORKER_CHECKER, _WORKER_SETUP_ERROR
    from multiprocessing.util import Finalize

    signal.signal(signal.SIGINT, signal.SIG_IGN)
    _watch_parent()
    try:
        _WORKER_CHECKER = checker_factory()
    except Exception as err:  # reported by the first task, which ends the run
        _WORKER_SETUP_ERROR = f"building the checker failed: {_format_exc(err)}"
        return
    Finalize(None, _close, args=(_WORKER_CHECKER,), exitpriority=10)


def _measure_in_process_worker(frame: Frame) -> dict[str, Any]:
    if _WORKER_SETUP_ERROR is not None:
        raise CheckerSetupError(_WORKER_SETUP_ERROR)
    return _WORKER_CHECKER.measure(frame)


@dataclass
class _Task:
    frame: Frame
    crashes: int = 0
    isolated: bool = False


def _new_pool(checker_factory: CheckerFactory, workers: int) -> cf.ProcessPoolExecutor:
    import multiprocessing

    return cf.ProcessPoolExecutor(
        max_workers=workers,
        mp_context=multiprocessing.get_context("spawn"),
        initializer=_init_process_worker,
        initargs=(checker_factory,),
    )


def _worker_processes(pool: cf.ProcessPoolExecutor) -> list[Any]:
    """The pool's worker processes right now (best effort: reads a private attribute)."""
    return list((getattr(pool, "_processes", None) or {}).values())


def _exit_codes(procs: Iterable[Any]) -> list[int]:
    """Exit codes of dead worker processes (collected while they ran: a broken pool clears its
    own table before we can read it). The pool SIGTERMs its other workers once one has died;
    those are left out."""
    codes = set()
    for p in procs:
        if p.exitcode is None:
            p.join(timeout=1.0)
        if p.exitcode not in (None, 0):
            codes.add(p.exitcode)
    return sorted(codes - {-signal.SIGTERM} or codes)


def _kill_pool(pool: cf.ProcessPoolExecutor) -> None:
    """Stop a pool now: cancel queued work and kill its workers (they may be hung)."""
    procs = list((getattr(pool, "_processes", None) or {}).values())
    pool.shutdown(wait=False, cancel_futures=True)
    for p in procs:
        if p.is_alive():
            p.kill()
    for p in procs:
        p.join(timeout=5)


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


def _fill(
    stop: threading.Event,
    inflight: dict[Any, _Task],
    retry: collections.deque[_Task],
    source: Iterator[Frame],
    exhausted: bool,
    max_inflight: int,
    submit: Callable[[_Task], bool],
) -> bool:
    """Submit work under the policy both pools share; returns whether ``source`` is exhausted.

    A frame suspected of crashing its worker (in ``retry``) runs alone: nothing else is
    submitted while it is in flight, and it waits until the pool is empty. Otherwise new frames
    are submitted until ``max_inflight`` are in flight. ``submit`` returns False when the pool
    refused the task (it then re-queued it itself).
    """
    while not stop.is_set():
        if any(t.isolated for t in inflight.values()):
            break
        if retry:
            if not inflight:
                task = retry.popleft()
                task.isolated = True
                submit(task)
            break
        if len(inflight) >= max_inflight or exhausted:
            break
        frame = next(source, None)
        if frame is None:
            return True
        if not submit(_Task(frame)):
            break
    return exhausted


def _iter_process(
    frames: Iterable[Frame],
    checker_factory: CheckerFactory,
    config: RunConfig,
    stop: threading.Event,
    error_record: ErrorRecord,
    stats: ExecutorStats,
) -> Iterator[dict[str, Any]]:
    from concurrent.futures.process import BrokenProcessPool

    workers = config.workers or default_workers()
    stats.workers = workers
    max_inflight = max(2, INFLIGHT_PER_WORKER * workers)
    source = iter(frames)
    exhausted = False
    retry: collections.deque[_Task] = collections.deque()
    inflight: dict[cf.Future, _Task] = {}
    noted = [False]
    pool = _new_pool(checker_factory, workers)
    procs: set[Any] = set()
    clean_exit = False
    logger.info(
        "process pool: %d workers (spawn), up to %d frames in flight", workers, max_inflight
    )

    def submit(task: _Task) -> bool:
        try:
            fut = pool.submit(_measure_in_process_worker, task.frame)
        except BrokenProcessPool:
            retry.appendleft(task)
            return False
        inflight[fut] = task
        procs.update(_worker_processes(pool))
        stats.submitted += 1
        return True

    try:
        while True:
            exhausted = _fill(stop, inflight, retry, source, exhausted, max_inflight, submit)
            _note_stop(stop, noted, len(inflight))
            if not inflight:
                if stop.is_set() or (exhausted and not retry):
                    break
                if retry:  # submit failed on a broken pool: rebuild below
                    _kill_pool(pool)
                    pool = _new_pool(checker_factory, workers)
                continue
            done, _ = cf.wait(inflight, timeout=1.0, return_when=cf.FIRST_COMPLETED)
            crashed: list[_Task] = []
            for fut in done:
                task = inflight.pop(fut)
                rec = _outcome(fut, task, crashed, config, stop, error_record, BrokenProcessPool)
                if rec is not None:
                    stats.yielded += 1
                    yield rec
            if not crashed:
                continue
            # the pool is broken: every other frame in flight fails too (or just finished)
            cf.wait(inflight, timeout=60)
            for fut in list(inflight):
                task = inflight.pop(fut)
                rec = _outcome(fut, task, crashed, config, stop, error_record, BrokenProcessPool)
                if rec is not None:
                    stats.yielded += 1
                    yield rec
            codes = _exit_codes(procs)
            _kill_pool(pool)
            procs.clear()
            stats.worker_crashes += 1
            how = _describe_exit(codes)
            if stop.is_set():
                logger.info("a worker died after the interrupt (%s); not retried", how)
            elif len(crashed) == 1:
                task = crashed[0]
                task.crashes += 1
                if task.crashes > config.retries:
                    if config.fail_fast:
                        raise RuntimeError(f"frame {task.frame.frame_id}: worker died ({how})")
                    logger.error(
                        "frame %s: its worker died %d times (%s); recorded as worker_crashed",
                        task.frame.frame_id,
                        task.crashes,
                        how,
                    )
                    stats.crashed_frames.append(task.frame.frame_id)
                    stats.yielded += 1
                    yield error_record(
                        task.frame,
                        "worker_crashed",
                        f"the worker process died while measuring this frame "
                        f"{task.crashes} times ({how})",
                    )
                else:
                    logger.warning(
                        "frame %s: its worker died (%s); retrying", task.frame.frame_id, how
                    )
                    retry.appendleft(task)
            else:
                logger.warning(
                    "a worker died (%s) with %d frames in flight; re-running them "
                    "one at a time to find the cause",
                    how,
                    len(crashed),
                )
                retry.extend(crashed)
            if not stop.is_set():
                pool = _new_pool(checker_factory, workers)
        stats.stopped = stop.is_set()
        clean_exit = True
    finally:
        if clean_exit:
            pool.shutdown(wait=True, cancel_futures=True)
        else:  # an exception or the consumer stopped iterating: do not wait for hung frames
            _kill_pool(pool)


def _outcome(
    fut: cf.Future,
    task: _Task,
    crashed: list[_Task],
    config: RunConfig,
    stop: threading.Event,
    error_record: ErrorRecord,
    broken_type: type[BaseException],
) -> dict[str, Any] | None:
    """Record of a finished future, or None (crashed -> appended to ``crashed``; cancelled)."""
    if fut.cancelled():
        return None
    err = fut.exception()
    if err is None:
        return fut.result()
    if isinstance(err, broken_type):
        crashed.append(task)
        return None
    if isinstance(err, CheckerSetupError):
        raise err
    if config.fail_fast:
        raise err
    if stop.is_set():
        return None
    logger.error("frame %s: internal error: %s", task.frame.frame_id, err)
    return error_record(task.frame, "internal_error", _format_exc(err))


# -- dask ------------------------------------------------------------------------------------
_DASK_LOCAL = threading.local()


def _dask_measure(token: str, checker_factory: CheckerFactory, frame: Frame) -> dict[str, Any]:
    """Task body: one checker per worker thread and run token (GL contexts are per thread).

    The checker of a run stays cached in its thread until the next run replaces it or the
    worker stops (workers of a long-lived cluster keep one mesh per thread meanwhile).
    """
    cached = getattr(_DASK_LOCAL, "checker", None)
    if cached is None or cached[0] != token:
        if cached is not None:
            _close(cached[1])
        _DASK_LOCAL.checker = None
        _DASK_LOCAL.checker = (token, _build(checker_factory))
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


def _iter_dask(
    frames: Iterable[Frame],
    checker_factory: CheckerFactory,
    config: RunConfig,
    stop: threading.Event,
    error_record: ErrorRecord,
    stats: ExecutorStats,
) -> Iterator[dict[str, Any]]:
    from distributed import as_completed
    from distributed.scheduler import KilledWorker

    client, cluster = _dask_client(config)
    token = uuid.uuid4().hex[:12]
    inflight: dict[Any, _Task] = {}
    retry: collections.deque[_Task] = collections.deque()
    noted = [False]
    try:
        nthreads = sum(client.nthreads().values()) or 1
        stats.workers = nthreads
        max_inflight = max(2, INFLIGHT_PER_WORKER * nthreads)
        source = iter(frames)
        exhausted = False
        ac = as_completed()
        logger.info("Dask: %d worker threads, up to %d frames in flight", nthreads, max_inflight)

        def submit(task: _Task) -> bool:
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

        def fill() -> None:
            nonlocal exhausted
            exhausted = _fill(stop, inflight, retry, source, exhausted, max_inflight, submit)

        fill()
        for fut in ac:
            task = inflight.pop(fut)
            frame = task.frame
            rec: dict[str, Any] | None = None
            if fut.status == "finished":
                rec = fut.result()
            elif fut.status != "cancelled" and not stop.is_set():
                err = fut.exception()
                if isinstance(err, CheckerSetupError):
                    raise err
                if isinstance(err, KilledWorker):
                    rec = _dask_crash(task, err, retry, config, error_record, stats)
                else:
                    if config.fail_fast:
                        raise err
                    logger.error("frame %s: internal error: %s", frame.frame_id, err)
                    rec = error_record(frame, "internal_error", _format_exc(err))
            fut.release()
            if rec is not None:
                stats.yielded += 1
                yield rec
            _note_stop(stop, noted, len(inflight))
            fill()
        stats.stopped = stop.is_set()
    finally:
        if inflight:
            client.cancel(list(inflight))
        client.close()
        if cluster is not None:
            cluster.close()


def _dask_crash(
    task: _Task,
    err: BaseException,
    retry: collections.deque[_Task],
    config: RunConfig,
    error_record: ErrorRecord,
    stats: ExecutorStats,
) -> dict[str, Any] | None:
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
    logger.error(
        "frame %s: its worker died %d times; recorded as worker_crashed", fid, task.crashes
    )
    stats.crashed_frames.append(fid)
    return error_record(
        task.frame,
        "worker_crashed",
        f"the worker process died while measuring this frame {task.crashes} times "
        f"({type(err).__name__}: {err})",
    )
