"""measure/edge_path.py: the run config's edge settings reach the alignment (end-to-end runs of
the path are in test_edge_size.py and test_checker.py)."""

from __future__ import annotations

import numpy as np
import pytest

import pgt_check.geometry.edges as edges
from pgt_check.config import PRESETS, RunConfig
from pgt_check.measure.edge_path import measure_edges


class _Captured(Exception):
    pass


@pytest.mark.parametrize(
    ("settings", "expected"),
    [({}, {"select_model": False, "decision": "either", "model": "homography"}),
     (PRESETS["fast"], {"select_model": False}),
     ({"edges": {"select_model": True}}, {"select_model": True}),
     ({"edges": {"decision": "significance", "alpha": 0.02, "tile_grid": 3}},
      {"decision": "significance", "alpha": 0.02, "tile_grid": 3})],
)
def test_edge_settings_reach_the_alignment(monkeypatch, settings, expected) -> None:
    seen = {}

    def align(render_edges, photo_edges, config):
        seen["config"] = config
        raise _Captured

    monkeypatch.setattr(edges, "geometric_edges", lambda depth, k, cfg: "render edges")
    monkeypatch.setattr(edges, "photo_edges", lambda photo: "photo edges")
    monkeypatch.setattr(edges, "align_edges", align)
    cfg = RunConfig.from_dict(settings).edges

    class _Render:
        depth = np.ones((4, 4), np.float32)

    class _Cam:
        K = np.eye(3)

    with pytest.raises(_Captured):
        measure_edges(_Render(), np.zeros((4, 4, 3), np.float32), _Cam(), (1.0, 1.0), _Cam(), cfg)
    for key, value in expected.items():
        assert getattr(seen["config"], key) == value, key


# -- select_model "fallback": the cross-validated model only where the fixed one does not pass --
class _Reason:
    value = "low_support"


def _alignment(shift_px: float, ok: bool, model: str, tag: float):
    """An ``EdgeAlignment``-like result: a pure shift of ``shift_px`` (corner error = shift);
    its matched points are tagged with ``tag`` so the test sees whose points were kept."""
    from types import SimpleNamespace

    pts = np.full((5, 2), tag)
    return SimpleNamespace(
        success=ok, reason=None if ok else _Reason(), model=model, n_edges=100,
        n_photo_edges=120, support=0.5,
        photo_from_render=np.array([[1, 0, shift_px], [0, 1, 0], [0, 0, 1]], float),
        matches=SimpleNamespace(render_points=pts, photo_points=pts, depth=np.ones(5)),
    )


@pytest.mark.parametrize(
    ("mode", "fixed", "threshold", "calls", "error", "method", "points_from"),
    [("fallback", (3.0, True), 8.0, [False], 3.0, "edges", 1.0),  # passes: no second fit
     ("fallback", (12.0, True), 8.0, [False, True], 2.0, "edges:shift", 1.0),  # above threshold
     ("fallback", (3.0, False), 8.0, [False, True], 2.0, "edges:shift", 2.0),  # refused
     ("never", (12.0, True), 8.0, [False], 12.0, "edges", 1.0),
     ("always", (2.0, True), 8.0, [True], 2.0, "edges:shift", 1.0)],
)
def test_select_model_fallback(monkeypatch, mode, fixed, threshold, calls, error, method,
                               points_from) -> None:
    seen = []

    def align(render_edges, photo_edges, config):
        seen.append(config.select_model)
        if config.select_model:
            return _alignment(2.0, True, "shift", 2.0 if len(seen) > 1 else 1.0)
        return _alignment(fixed[0], fixed[1], "homography", 1.0)

    monkeypatch.setattr(edges, "geometric_edges", lambda depth, k, cfg: "render edges")
    monkeypatch.setattr(edges, "photo_edges", lambda photo: "photo edges")
    monkeypatch.setattr(edges, "align_edges", align)
    from pgt_check.types import Camera

    cam = Camera.pinhole(64, 48, 50.0, 50.0, 31.5, 23.5)

    class _Render:
        depth = np.ones((48, 64), np.float32)

    cfg = RunConfig.from_dict({"edges": {"select_model": mode}}).edges
    out = measure_edges(_Render(), np.zeros((48, 64, 3), np.float32), cam, (1.0, 1.0), cam, cfg,
                        threshold)
    assert seen == calls
    assert out.measurement.corner_error_px == pytest.approx(error)
    assert out.measurement.method == method
    np.testing.assert_array_equal(out.render_points, np.full((5, 2), points_from))


def test_select_model_setting() -> None:
    from pgt_check.errors import ConfigError

    assert RunConfig().edges.select_model == "fallback"
    assert RunConfig.from_dict({"edges": {"select_model": True}}).edges.select_model == "always"
    assert RunConfig.from_dict({"edges": {"select_model": False}}).edges.select_model == "never"
    with pytest.raises(ConfigError, match="select_model"):
        RunConfig.from_dict({"edges": {"select_model": "sometimes"}})
