"""Fixtures of the stability suite; the scene builders live in stab_scenes.py (put on sys.path
here, like tests/pgt_check/report/report_testdata.py is through pyproject)."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))

from stab_scenes import MeshData, Scene, box_room_mesh  # noqa: E402


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
