"""The scan-like generated scene (issue #29): rounded, holed, decimated mesh; photos with
objects the mesh lacks."""

from __future__ import annotations

import numpy as np

from pgt_eval import boxes_scene, make_scan_like_scene, scan_like_mesh


def _clean():
    import trimesh

    return trimesh.util.concatenate(list(boxes_scene(0).geometry.values()))


def _takes_seed() -> bool:
    import inspect

    import trimesh

    return "seed" in inspect.signature(trimesh.Trimesh.sample).parameters


def test_scan_like_mesh_is_rounded_holed_and_deterministic():
    from scipy.spatial import cKDTree

    clean = _clean()
    a, b = scan_like_mesh(clean, seed=3), scan_like_mesh(clean, seed=3)
    np.testing.assert_array_equal(a.vertices, b.vertices)
    assert not a.is_watertight  # holes
    # vertices off the clean surfaces (noise, rounded edges), but close to them
    surface = np.asarray(clean.sample(200_000, seed=0) if _takes_seed() else clean.sample(200_000))
    dist, _ = cKDTree(surface).query(a.vertices[::50])
    assert 0.001 < np.median(dist) < 0.05 and dist.max() < 0.3
    # no colours kept from the clean mesh
    assert len(np.unique(a.visual.vertex_colors[:, :3], axis=0)) == 1


def test_scan_like_scene_files(tmp_path):
    from pgt_check.io import read_trajectory

    traj = read_trajectory(make_scan_like_scene(tmp_path, n_frames=3))
    assert len(traj) == 3 and (tmp_path / "scan.ply").is_file()
    assert all(f.image_file.is_file() for f in traj.frames)
