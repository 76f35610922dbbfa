"""Third audit (#39), the Python API after an input changed in place: the same ``out`` and a
changed mesh measures the frames again (the CLI's ``--resume``, the API's default); it never
returns the old results and never refuses with "holds results of other measurement settings"
unless asked to (``resume=False``); ``overwrite=True`` starts fresh."""

from __future__ import annotations

from pathlib import Path

import pytest

from pgt_check.errors import InputError

FAST = {"report_details": 0, "enhance": {"mode": "never"}, "correct": {"frames": "none"}}


def move_mesh(path: Path, dx: float) -> None:
    """Rewrite the mesh file at ``path`` moved by ``dx`` scene units along x (same path)."""
    import trimesh

    scene = trimesh.load(path)
    scene.apply_translation([dx, 0.0, 0.0])
    path.write_bytes(scene.export(file_type=path.suffix.lstrip(".")))


def test_api_mesh_moved_in_place_is_measured_again(scene, tmp_path, case):
    from pgt_check.api import check

    out = str(tmp_path / "out")
    traj, mesh = scene / "trajectories.txt", scene / "mesh.glb"
    first = check(traj, mesh, out=out, limit=2, **FAST)
    move_mesh(mesh, 0.3)
    again = check(traj, mesh, out=out, limit=2, **FAST)
    fresh = check(traj, mesh, out=str(tmp_path / "fresh"), limit=2, **FAST)
    case("API: mesh moved 0.3 m in place, check() again into the same out",
         "measured again: FAIL as a fresh out",
         f"first {list(first['verdict'])}, again {list(again['verdict'])}, "
         f"fresh {list(fresh['verdict'])}")
    assert list(first["verdict"]) == ["PASS", "PASS"]
    assert list(again["verdict"]) == list(fresh["verdict"])
    assert "PASS" not in set(again["verdict"])
    assert again.attrs["summary"]["gate"]["passed"] is False
    assert again.attrs["summary"]["executor"]["frames_reused"] == 0


def test_api_resume_false_refuses_and_overwrite_starts_fresh(scene, tmp_path):
    from pgt_check.api import check

    out = str(tmp_path / "out")
    traj, mesh = scene / "trajectories.txt", scene / "mesh.glb"
    check(traj, mesh, out=out, limit=1, **FAST)
    same = check(traj, mesh, out=out, limit=1, **FAST)  # unchanged: reused
    assert same.attrs["summary"]["executor"]["frames_reused"] == 1
    move_mesh(mesh, 0.3)
    with pytest.raises(InputError, match="other measurement settings"):
        check(traj, mesh, out=out, limit=1, resume=False, **FAST)
    fresh = check(traj, mesh, out=out, limit=1, overwrite=True, **FAST)
    assert list(fresh["verdict"]) != ["PASS"]
    assert fresh.attrs["summary"]["executor"]["frames_reused"] == 0
