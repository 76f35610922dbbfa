"""Progress of a long loop over frames: a tqdm bar on a terminal, log lines elsewhere (CI)."""

from __future__ import annotations

import logging
import time
from collections.abc import Callable

logger = logging.getLogger(__name__)

__all__ = ["PROGRESS_INTERVAL_S", "frame_progress", "log_progress"]


#: seconds between progress lines when stderr is not a terminal (CI logs)
PROGRESS_INTERVAL_S = 5.0


def frame_progress(iterable, total: int, desc: str):
    """A tqdm bar on a terminal; otherwise a log line every ``PROGRESS_INTERVAL_S``."""
    import sys

    if not sys.stderr.isatty():
        return log_progress(iterable, total, desc)
    try:
        from tqdm import tqdm
    except ImportError:  # pragma: no cover - tqdm is a core dependency
        return iterable
    return tqdm(iterable, total=total, desc=desc, unit="frame")


def log_progress(iterable, total: int, desc: str, interval_s: float | None = None,
                 clock: Callable[[], float] = time.monotonic):
    """Yield from ``iterable``, logging ``desc: done/total frames (..%), rate, time left`` at
    INFO every ``interval_s`` seconds (default ``PROGRESS_INTERVAL_S``) and once at the end."""
    interval = PROGRESS_INTERVAL_S if interval_s is None else interval_s
    t0 = last = clock()
    done = logged = 0

    def line(now: float) -> None:
        rate = done / max(now - t0, 1e-9)
        left = f", about {(total - done) / rate:.0f} s left" if 0 < rate and done < total else ""
        pct = f" ({100.0 * done / total:.0f} %)" if total else ""
        logger.info("%s: %d/%d frames%s, %.2f frames/s%s", desc, done, total, pct, rate, left)

    for item in iterable:
        yield item
        done += 1
        now = clock()
        if now - last >= interval:
            last, logged = now, done
            line(now)
    if done and logged != done:
        line(clock())
