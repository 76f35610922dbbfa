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
