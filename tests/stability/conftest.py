"""Fixtures of the stability suite; the scene builders live in stab_scenes.py (on sys.path
through pyproject's pythonpath, like tests/pgt_check/report/report_testdata.py)."""

from __future__ import annotations

import pytest
from stab_scenes import MeshData, Scene, box_room_mesh


@pytest.fixture
def scene_factory(tmp_path):
    made: list[Scene] = []

    def make(mesh: MeshData) -> Scene:
        s = Scene(mesh, tmp_path)
        made.append(s)
        return s

    yield make
    for s in made:
        s.close()


@pytest.fixture(scope="module")
def room_mesh() -> MeshData:
    return box_room_mesh()
