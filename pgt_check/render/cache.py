"""A renderer that keeps its latest renders: a frame's references are mostly its neighbours,
which the run checks too, so the reference views the enhancement renders (its depth) are the
views those frames render for themselves, a moment earlier or later (issue #28: compute each
image once). Rendering is deterministic in (camera, pose), so a kept render is the one a new
render would give; its arrays are read-only, so no user can change it for the next.
"""

from __future__ import annotations

import logging
from collections import OrderedDict
from typing import Any

import numpy as np

from pgt_check.render.base import Render, Renderer
from pgt_check.types import Camera

logger = logging.getLogger(__name__)

#: bytes of renders kept per renderer (a 640 x 480 render is about 5 MB with its depth and
#: coverage; the oldest are dropped first)
DEFAULT_MAX_BYTES = 64 * 2**20


def _key(camera: Camera, world_from_cam: np.ndarray) -> tuple:
    pose = np.ascontiguousarray(world_from_cam, dtype=np.float64)
    return (camera.model, camera.width, camera.height, tuple(map(float, camera.params)),
            pose.shape, pose.tobytes())


def _nbytes(r: Render) -> int:
    return int(r.rgb.nbytes + r.depth.nbytes + r.coverage.nbytes)


class CachedRenderer:
    """Wraps a ``Renderer``: ``render`` returns the kept render of the same camera and pose
    (at most ``max_bytes`` kept, least recently used dropped first); everything else is the
    wrapped renderer's."""

    def __init__(self, renderer: Renderer, max_bytes: int = DEFAULT_MAX_BYTES) -> None:
        if max_bytes < 0:
            raise ValueError(f"max_bytes must be >= 0, got {max_bytes}")
        self.inner = renderer
        self.max_bytes = int(max_bytes)
        self._kept: OrderedDict[tuple, Render] = OrderedDict()
        self._bytes = 0
        self.hits = 0
        self.misses = 0

    @property
    def shading(self) -> str:
        return self.inner.shading

    def render(self, camera: Camera, world_from_cam: np.ndarray) -> Render:
        key = _key(camera, world_from_cam)
        kept = self._kept.get(key)
        if kept is not None:
            self._kept.move_to_end(key)
            self.hits += 1
            return kept
        self.misses += 1
        out = self.inner.render(camera, world_from_cam)
        size = _nbytes(out)
        if size > self.max_bytes:
            return out
        for a in (out.rgb, out.depth, out.coverage):
            a.setflags(write=False)
        self._kept[key] = out
        self._bytes += size
        while self._bytes > self.max_bytes:
            _, old = self._kept.popitem(last=False)
            self._bytes -= _nbytes(old)
        return out

    def clear(self) -> None:
        self._kept.clear()
        self._bytes = 0

    def close(self) -> None:
        self.clear()
        self.inner.close()

    def __getattr__(self, name: str) -> Any:
        # only reached for attributes this class lacks (the backend's own, e.g. its mesh)
        if name == "inner":
            raise AttributeError(name)
        return getattr(self.inner, name)
