"""OpenCV's thread count per process (``RunConfig.threads``).

pgt-check works on small images (matching at 320 px) with Python steps between the OpenCV
calls; OpenCV's idle worker threads keep spinning after each call and take the cores from those
steps and from the renderer's threads. On 2 cores one thread made the default run both faster
and cheaper, with identical results (reports/pipeline_timing.md). More cores are used by
spreading frames over processes (``--executor process``), one OpenCV thread each.
"""

from __future__ import annotations

import contextlib
import logging
from collections.abc import Iterator

logger = logging.getLogger(__name__)


def set_opencv_threads(n: int | None) -> int:
    """Set OpenCV's threads for this process (None: OpenCV's default, every core); returns the
    count before, for ``restore``."""
    import cv2

    before = int(cv2.getNumThreads())
    if n is not None and n < 1:
        raise ValueError(f"threads must be >= 1 or None, got {n}")
    cv2.setNumThreads(-1 if n is None else int(n))
    logger.debug("OpenCV threads: %d -> %d", before, cv2.getNumThreads())
    return before


@contextlib.contextmanager
def opencv_threads(n: int | None) -> Iterator[None]:
    """OpenCV's threads set to ``n`` inside the block and restored after it (the Python API
    runs in the caller's process: its own OpenCV setting is left as it was)."""
    import cv2

    before = set_opencv_threads(n)
    try:
        yield
    finally:
        cv2.setNumThreads(before)
