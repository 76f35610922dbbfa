"""Threads per process of OpenCV and of the BLAS libraries (``RunConfig.threads``).

pgt-check works on small images (matching at 320 px) and small matrices, with Python steps
between the library calls. OpenCV's and OpenBLAS's idle worker threads keep spinning after each
call and take the cores from those steps and from the renderer's threads: on 2 cores one
thread each made the default run cheaper (about a quarter less CPU) and no slower, with
identical results (reports/pipeline_timing.md; single-threaded SIFT is slower per frame at
640 px and above: reports/error_vs_runtime.md). More cores are used by spreading frames over
processes (``--executor process``), one thread each.

``run_threads(n)`` sets them for a block and restores the caller's settings after it (the
Python API runs in the caller's process); ``limit_threads(n)`` applies them where libraries
were loaded since (a BLAS library counts from its loading: trimesh loads scipy's with the mesh),
through the enclosing block, or for the rest of the process in a worker.

At most ``MAX_THREADS_PER_CORE`` x the usable cores are applied (``capped``): ``--threads 4096``
made a 3-frame run 13x slower (issue #39 item 13). The setting itself is kept as given (a
config file replayed on a bigger machine keeps its meaning); the run warns once. The number of
threads never changes a result, only the speed.
"""

from __future__ import annotations

import contextlib
import logging
import os
from collections.abc import Iterator
from typing import Any

logger = logging.getLogger(__name__)

#: threads applied at most per usable core (more only wait on each other)
MAX_THREADS_PER_CORE = 4


def usable_cores() -> int:
    """The cores this process may run on (its CPU affinity), at least 1."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - not Linux
        return max(1, os.cpu_count() or 1)


def capped(n: int | None, warn: bool = False) -> int | None:
    """``n`` threads, at most ``MAX_THREADS_PER_CORE`` x ``usable_cores()`` (None stays None);
    with ``warn`` a WARNING says when it was capped."""
    if n is None:
        return None
    cap = MAX_THREADS_PER_CORE * usable_cores()
    if n > cap and warn:
        logger.warning("threads %d is more than %d x the %d usable core(s): using %d (more "
                       "threads only wait on each other; the results are the same)",
                       n, MAX_THREADS_PER_CORE, usable_cores(), cap)
    return min(n, cap)


class ThreadLimits:
    """``n`` threads (None: the libraries' defaults, left alone; capped: ``capped``) for OpenCV
    and every BLAS library loaded when ``apply`` is called; ``restore`` undoes every
    ``apply``."""

    def __init__(self, n: int | None, warn: bool = False) -> None:
        if n is not None and n < 1:
            raise ValueError(f"threads must be >= 1 or None, got {n}")
        self.n = capped(n, warn)
        self._cv_before: int | None = None
        self._blas: list[Any] = []  # threadpoolctl limiters, in the order applied

    def apply(self) -> None:
        if self.n is None:
            return
        import cv2

        if self._cv_before is None:
            self._cv_before = int(cv2.getNumThreads())
        cv2.setNumThreads(int(self.n))
        try:
            from threadpoolctl import threadpool_limits
        except ImportError:  # a dependency; without it only the speed differs
            logger.warning("threadpoolctl is not installed: the BLAS libraries keep their "
                           "default threads (pip install threadpoolctl)")
            return
        self._blas.append(threadpool_limits(limits=int(self.n), user_api="blas"))
        logger.debug("threads: OpenCV and BLAS at %d", self.n)

    def restore(self) -> None:
        for limiter in reversed(self._blas):
            limiter.restore_original_limits()
        self._blas.clear()
        if self._cv_before is not None:
            import cv2

            cv2.setNumThreads(self._cv_before)
            self._cv_before = None


_ACTIVE: list[ThreadLimits] = []


@contextlib.contextmanager
def run_threads(n: int | None) -> Iterator[ThreadLimits]:
    """OpenCV and BLAS at ``n`` threads inside the block; the settings before it come back
    after it, also for libraries first limited inside it (``limit_threads``). Warns when ``n``
    is capped (in the outermost block only)."""
    limits = ThreadLimits(n, warn=not _ACTIVE)
    _ACTIVE.append(limits)
    try:
        limits.apply()
        yield limits
    finally:
        _ACTIVE.remove(limits)
        limits.restore()


def limit_threads(n: int | None) -> None:
    """Apply ``n`` to the libraries loaded by now: through the innermost ``run_threads`` block
    of this process (restored at its end), else for the rest of the process (a worker)."""
    if _ACTIVE:
        _ACTIVE[-1].apply()
    else:
        ThreadLimits(n).apply()
