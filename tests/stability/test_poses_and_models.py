"""Quaternion edge cases through the LaMAR reader, and planar vs strongly 3-D scenes.

Why a homography verdict stays meaningful on a 3-D scene: with the correct pose, render and
photo see every surface point at the same pixel, so the render->photo map is the identity
whatever the depth structure (corner error ~0 -> PASS). A pure rotation error is exactly a
homography (K R K^-1) for any scene. A translation error t moves each point by f * t / depth:
on a plane this is again a homography (FAIL with its corner error), but on a 3-D scene the
motion differs with depth (parallax), the homography only fits one depth layer, and the frame
gets a large residual corner error (FAIL) or too few consistent inliers (UNVERIFIABLE); it is
never silently PASS just because the model is wrong.
"""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from stab_scenes import CAM, box_mesh, look_at, noise_texture, plane_mesh

from pgt_check.errors import InputError
from pgt_check.geometry.transforms import make_rigid
from pgt_check.io import read_trajectory, write_lamar
from pgt_check.render import load_mesh, mesh_from_trimesh
from pgt_check.types import Trajectory


def _rewrite_quats(path, edit) -> None:
    lines = path.read_text().splitlines()
    out = []
    for line in lines:
        if line.startswith("#"):
            out.append(line)
            continue
        cols = [c.strip() for c in line.split(",")]
        q = np.array([float(c) for c in cols[2:6]])
        q = edit(len(out) - 1, q)
        out.append(", ".join(cols[:2] + [repr(float(v)) for v in q] + cols[6:]))
    path.write_text("\n".join(out) + "\n")


def test_non_unit_and_antipodal_quaternions(tmp_path, sample_scene, scene_factory):
    """Sample frames written to LaMAR with q scaled by 1.004 (normalised on read), -q
    (antipodal: same rotation) and -q + 1e-9 noise: each reads back to the same pose and gets
    the same verdict (PASS for frame 0..2). A quaternion of norm 2 is a clean InputError."""
    traj = read_trajectory(sample_scene / "trajectories.txt", "auto")
    frames = list(traj.frames[:3])
    write_lamar(Trajectory(tuple(frames), "orig"), tmp_path / "lamar")
    traj_file = tmp_path / "lamar" / "trajectories.txt"
    edits = {0: lambda q: q * 1.004, 1: lambda q: -q, 2: lambda q: -q + 1e-9}
    _rewrite_quats(traj_file, lambda i, q: edits[i](q))
    back = read_trajectory(traj_file, "lamar")
    for f, g in zip(frames, back.frames, strict=True):
        np.testing.assert_allclose(g.world_from_cam, f.world_from_cam, atol=1e-8)
    s = scene_factory(load_mesh(sample_scene / "mesh.glb"))
    recs = s.check(back.frames)
    assert [r["verdict"] for r in recs] == ["PASS"] * 3

    _rewrite_quats(traj_file, lambda i, q: q * 2.0 if i == 0 else q)
    with pytest.raises(InputError, match="quaternion"):
        read_trajectory(traj_file, "lamar")


def _city_mesh():
    """Strongly 3-D: a textured ground and boxes from 2 m to 12 m deep."""
    ground = plane_mesh(noise_texture(50), half=15.0, z=0.0)
    parts = []
    for i, (x, y, size) in enumerate(
        [(-1.0, 2.5, 1.0), (1.2, 4.0, 1.4), (-2.5, 7.0, 2.0), (2.5, 10.0, 3.0), (0.0, 12.0, 2.5)]
    ):
        parts += box_mesh([x, y, size / 2], size, seed=60 + 7 * i)
    boxes = mesh_from_trimesh(trimesh.Scene(parts))
    from dataclasses import replace

    return replace(
        ground,
        vertices=np.vstack([ground.vertices, boxes.vertices]),
        faces=np.vstack([ground.faces, boxes.faces + len(ground.vertices)]),
        uv=np.vstack([ground.uv, boxes.uv]),
        textures=ground.textures + boxes.textures,
        face_texture=np.concatenate([ground.face_texture, boxes.face_texture + 1]),
        colors=np.vstack([ground.colors, boxes.colors]),
        offset=np.zeros(3),
    )


def test_planar_scene_translation_is_a_homography(scene_factory):
    """Planar wall 3 m ahead: the correct pose PASSes; a 0.15 m sideways translation is an
    exact homography (shift f * t / d = 200 * 0.15 / 3 = 10 px) -> FAIL with a corner error of
    about 10 px and almost every match an inlier."""
    s = scene_factory(plane_mesh(noise_texture(70), half=3.0, z=0.0))
    pose = look_at([0.0, 0.0, 3.0], [0.0, 0.0, 0.0], up=(0.0, 1.0, 0.0))
    moved = pose @ make_rigid(np.eye(3), [0.15, 0.0, 0.0])
    good, bad = s.check([s.frame(CAM, pose), s.frame(CAM, pose, moved)])
    assert good["verdict"] == "PASS" and good["corner_error_px"] < 0.5
    assert bad["verdict"] == "FAIL"
    assert bad["corner_error_px"] == pytest.approx(10.0, rel=0.1)
    assert bad["inlier_ratio"] > 0.8


def test_3d_scene_translation_is_not_a_silent_pass(scene_factory):
    """Strongly 3-D scene (ground + boxes 2..12 m): the correct pose PASSes (identity whatever
    the depth); pure translation errors (0.3 m sideways, 0.5 m forward) create parallax that
    no homography explains -> FAIL or UNVERIFIABLE, never PASS; where a homography was fitted,
    its inlier ratio is lower than for the correct pose."""
    s = scene_factory(_city_mesh())
    pose = look_at([0.0, -2.0, 1.6], [0.0, 8.0, 0.8])
    frames = [
        s.frame(CAM, pose),
        s.frame(CAM, pose, pose @ make_rigid(np.eye(3), [0.3, 0.0, 0.0])),
        s.frame(CAM, pose, pose @ make_rigid(np.eye(3), [0.0, 0.0, 0.5])),
    ]
    recs = s.check(frames)
    assert recs[0]["verdict"] == "PASS" and recs[0]["corner_error_px"] < 1.0, recs[0]["reason"]
    for r in recs[1:]:
        assert r["verdict"] in ("FAIL", "UNVERIFIABLE"), r
        if r["corner_error_px"] is not None:
            assert r["inlier_ratio"] < recs[0]["inlier_ratio"]
