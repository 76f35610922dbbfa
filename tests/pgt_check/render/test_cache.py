"""``render.cache.CachedRenderer``: the same (camera, pose) is rendered once, the kept render is
read-only, memory is bounded, and the real backend gives the same render either way."""

from __future__ import annotations

import numpy as np
import pytest

from pgt_check.render.base import Render
from pgt_check.render.cache import CachedRenderer
from pgt_check.types import Camera

CAM = Camera.pinhole(32, 24, 30.0, 30.0, 15.5, 11.5)


class Counting:
    shading = "vertex"

    def __init__(self):
        self.calls = 0
        self.closed = False
        self.mesh = "the backend's own attribute"

    def render(self, camera, world_from_cam):
        self.calls += 1
        r = Render.empty(camera.height, camera.width, self.shading)
        r.depth[...] = float(np.asarray(world_from_cam)[0, 3]) + self.calls
        return r

    def close(self):
        self.closed = True


def _pose(x: float) -> np.ndarray:
    p = np.eye(4)
    p[0, 3] = x
    return p


def test_the_same_view_is_rendered_once_and_kept_read_only():
    inner = Counting()
    r = CachedRenderer(inner)
    a = r.render(CAM, _pose(1.0))
    b = r.render(CAM, _pose(1.0))
    assert b is a and inner.calls == 1 and (r.hits, r.misses) == (1, 1)
    with pytest.raises(ValueError):
        a.depth[0, 0] = 5.0  # a user cannot change the render the next one gets
    # another pose or another camera is rendered anew
    assert r.render(CAM, _pose(1.0 + 1e-12)) is not a
    assert r.render(CAM.scaled(2.0), _pose(1.0)) is not a
    assert inner.calls == 3
    assert r.shading == "vertex" and r.mesh == inner.mesh
    r.close()
    assert inner.closed


def test_memory_is_bounded_oldest_dropped_first():
    one = Render.empty(CAM.height, CAM.width, "vertex")
    size = one.rgb.nbytes + one.depth.nbytes + one.coverage.nbytes
    inner = Counting()
    r = CachedRenderer(inner, max_bytes=2 * size)
    first = r.render(CAM, _pose(0.0))
    r.render(CAM, _pose(1.0))
    r.render(CAM, _pose(0.0))  # used again: kept over pose 1
    r.render(CAM, _pose(2.0))  # drops pose 1
    assert r.render(CAM, _pose(0.0)) is first
    calls = inner.calls
    r.render(CAM, _pose(1.0))
    assert inner.calls == calls + 1
    # a render larger than the whole budget is returned, not kept
    tiny = CachedRenderer(Counting(), max_bytes=size - 1)
    x = tiny.render(CAM, _pose(0.0))
    assert tiny.render(CAM, _pose(0.0)) is not x
    x.depth[0, 0] = 1.0  # not kept, so still writable
    with pytest.raises(ValueError, match="max_bytes"):
        CachedRenderer(Counting(), max_bytes=-1)


def test_real_backend_kept_render_equals_a_new_render(sample_scene):
    from pgt_check.io import read_trajectory
    from pgt_check.render import load_mesh, make_renderer

    frame = read_trajectory(sample_scene / "trajectories.txt").frames[0]
    mesh = load_mesh(sample_scene / "mesh.glb")
    plain = make_renderer(mesh)
    cached = CachedRenderer(make_renderer(mesh))
    try:
        want = plain.render(frame.camera, frame.world_from_cam)
        cached.render(frame.camera, frame.world_from_cam)
        got = cached.render(frame.camera, frame.world_from_cam)
        assert cached.hits == 1
        assert np.array_equal(got.rgb, want.rgb) and np.array_equal(got.depth, want.depth)
        assert np.array_equal(got.coverage, want.coverage)
    finally:
        plain.close()
        cached.close()
