"""Shared parts of the executors: the checker protocol, stats, failure measurements and the
submission policy both pools use."""

from __future__ import annotations

import collections
import contextlib
import logging
import os
import signal
import threading
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from typing import Any, Protocol

from pgt_check.errors import SetupError
from pgt_check.measure.record import FrameMeasurement, MeasureReason, failed_measurement
from pgt_check.measure.steps import format_exception
from pgt_check.types import Frame

logger = logging.getLogger(__name__)

#: submitted-but-unfinished frames per worker (bounds memory, keeps workers busy)
INFLIGHT_PER_WORKER = 2


class Checker(Protocol):
    def measure(self, frame: Frame) -> FrameMeasurement: ...


CheckerFactory = Callable[[], Checker]


class CheckerSetupError(SetupError, RuntimeError):
    """Building the checker failed in a worker (bad mesh, missing GL): the run cannot go on.

    A ``SetupError`` (so an ``InputError``): the CLI exits 2 with one line and the Python API
    raises it as documented; still a RuntimeError for callers that caught it as one. The
    message is one line (the cause's type and message); ``detail`` holds its traceback."""

    def __init__(self, message: str, detail: str = "") -> None:
        super().__init__(message)
        self.detail = detail


def checker_setup_error(err: BaseException) -> CheckerSetupError:
    """The CheckerSetupError of a checker factory that raised ``err``: a one-line message, the
    traceback in ``detail`` (logged at DEBUG)."""
    cause = " ".join(str(err).split())[:500]
    detail = format_exception(err)
    logger.debug("building the checker failed:\n%s", detail)
    return CheckerSetupError(
        f"building the checker failed: {type(err).__name__}: {cause or 'no message'}", detail
    )


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


@dataclass
class Task:
    """One frame in flight; ``isolated`` = it runs alone (suspected of crashing its worker)."""

    frame: Frame
    crashes: int = 0
    isolated: bool = False


def default_workers() -> int:
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - not Linux
        return max(1, os.cpu_count() or 1)


#: seconds a run may take after SIGTERM to finish its frames in progress before it is ended
#: anyway (a stuck frame must not outlive the CI cancel; ``docker stop`` kills after 10 s)
TERM_GRACE_S = 3.0


@contextlib.contextmanager
def stop_on_sigint() -> Iterator[threading.Event]:
    """While active, the first SIGINT or SIGTERM sets the yielded event; a second raises
    KeyboardInterrupt, and so does the end of ``TERM_GRACE_S`` after a SIGTERM (a frame stuck
    in a call that never returns cannot hold the run).

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
        if signum == signal.SIGTERM and hasattr(signal, "setitimer"):
            signal.setitimer(signal.ITIMER_REAL, max(TERM_GRACE_S, 1e-3))

    def deadline(signum: int, frame: Any) -> None:
        logger.warning("still busy %.0f s after SIGTERM: stopping now", TERM_GRACE_S)
        raise KeyboardInterrupt

    # SIGTERM (CI cancel, docker stop, kill) is handled like SIGINT
    signums = [signal.SIGINT, signal.SIGTERM]
    previous = {s: signal.signal(s, handler) for s in signums}
    if hasattr(signal, "SIGALRM"):
        previous[signal.SIGALRM] = signal.signal(signal.SIGALRM, deadline)
    try:
        yield stop
    finally:
        if hasattr(signal, "setitimer"):
            signal.setitimer(signal.ITIMER_REAL, 0)
        for s, h in previous.items():
            signal.signal(s, h)


def internal_error(frame: Frame, err: BaseException) -> FrameMeasurement:
    """The measurement of a frame whose ``measure`` raised."""
    logger.error("frame %s: internal error: %s", frame.frame_id, err)
    return failed_measurement(frame, MeasureReason.INTERNAL_ERROR, format_exception(err))


def worker_crashed(task: Task, how: str) -> FrameMeasurement:
    """The measurement of a frame whose worker died ``task.crashes`` times."""
    logger.error(
        "frame %s: its worker died %d times (%s); recorded as worker_crashed",
        task.frame.frame_id,
        task.crashes,
        how,
    )
    return failed_measurement(
        task.frame,
        MeasureReason.WORKER_CRASHED,
        f"the worker process died while measuring this frame {task.crashes} times ({how})",
    )


def quiet_sigterm() -> None:
    """Give SIGTERM back to Python in this process (its main thread): pycolmap's import
    installs glog's crash handler for SIGTERM too, so a worker the pool terminates after
    another one died, or a CI cancel of the process group, printed a native stack dump
    ("*** SIGTERM received ... stack trace", issue #39 item 10). pycolmap is imported here
    first (where installed: a later import installs nothing), then SIGTERM gets Python's own
    handler again (in a worker: the default, which ends it quietly). The real crash signals
    (SIGSEGV, SIGABRT, ...) keep their dump."""
    try:
        import pycolmap  # noqa: F401
    except ImportError:
        pass
    try:
        signal.signal(signal.SIGTERM, signal.getsignal(signal.SIGTERM) or signal.SIG_DFL)
    except ValueError:  # not the main thread
        pass


def build_checker(checker_factory: CheckerFactory) -> Checker:
    try:
        return checker_factory()
    except Exception as err:
        raise checker_setup_error(err) from err


class CheckerLender:
    """One checker, owned here and lent out: built by ``factory`` on first need (or given
    already built), closed by ``close``. The one way a checker is shared between passes:

    - ``borrow()``: the checker itself, for this process's own calls (``close`` stays here);
    - ``lend()``: a ``CheckerFactory`` for an executor pass that must not close it (the serial
      executor closes what its factory returns; here that is a no-op);
    - ``hand_over()``: a ``CheckerFactory`` whose first call gives the built checker away (the
      taker closes it) and later calls build new ones with ``factory`` (the serial main pass
      measuring with the checker the preflight built).
    """

    def __init__(self, factory: Callable[[], Any], checker: Any = None) -> None:
        self._factory, self._checker = factory, checker

    def borrow(self) -> Any:
        if self._checker is None:
            self._checker = self._factory()
        return self._checker

    def lend(self) -> _Lent:
        return _Lent(self.borrow())

    def hand_over(self) -> Any:
        if self._checker is not None:
            checker, self._checker = self._checker, None
            return checker
        return self._factory()

    def close(self) -> None:
        """Close the checker if it was built and not handed over."""
        if self._checker is not None:
            self._checker.close()
            self._checker = None


class _Lent:
    """A lent checker: measures with its owner's, closing is left to the owner."""

    def __init__(self, checker: Any) -> None:
        self._checker = checker

    def measure(self, frame: Frame, keep: Any = None) -> FrameMeasurement:
        return self._checker.measure(frame, keep)

    def close(self) -> None:
        pass


def close_checker(checker: Any) -> None:
    close = getattr(checker, "close", None)
    if callable(close):
        try:
            close()
        except Exception:  # closing must not hide the run's result
            logger.exception("closing the checker failed")


def note_stop(stop: threading.Event, noted: list[bool], inflight: int) -> None:
    if stop.is_set() and not noted[0]:
        noted[0] = True
        logger.warning(
            "interrupt: finishing %d frames in flight, then stopping (Ctrl-C again aborts now)",
            inflight,
        )


def fill(
    stop: threading.Event,
    inflight: dict[Any, Task],
    retry: collections.deque[Task],
    source: Iterator[Frame],
    exhausted: bool,
    max_inflight: int,
    submit: Callable[[Task], bool],
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
        if not submit(Task(frame)):
            break
    return exhausted
