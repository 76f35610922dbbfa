from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from pgt_check.render import MeshData, load_mesh, mesh_from_trimesh


def _grid_mesh(n: int = 30) -> MeshData:
    xs, ys = np.meshgrid(np.linspace(0, 1, n), np.linspace(0, 1, n))
    v = np.stack([xs.ravel(), ys.ravel(), 0.1 * np.sin(6 * xs.ravel())], axis=1)
    idx = np.arange(n * n).reshape(n, n)
    a, b, c, d = idx[:-1, :-1], idx[:-1, 1:], idx[1:, 1:], idx[1:, :-1]
    f = np.concatenate(
        [np.stack([a, b, c], -1).reshape(-1, 3), np.stack([a, c, d], -1).reshape(-1, 3)]
    )
    colors = np.stack([xs.ravel(), ys.ravel(), np.zeros(n * n)], axis=1)
    return MeshData(
        vertices=v + 1e6, faces=f, shading="vertex", colors=colors, offset=np.array([1e6 + 0.5] * 3)
    )


def test_import_is_light():
    code = (
        "import sys, pgt_check.render; "
        "assert 'moderngl' not in sys.modules and 'trimesh' not in sys.modules"
    )
    subprocess.run([sys.executable, "-c", code], check=True)


def test_without_colour_keeps_geometry():
    mesh = _grid_mesh()
    grey = mesh.without_colour()
    assert grey.shading == "shaded" and grey.colors is None
    np.testing.assert_array_equal(grey.vertices, mesh.vertices)
    np.testing.assert_array_equal(grey.offset, mesh.offset)


@pytest.mark.parametrize("quadric", [True, False])
def test_decimated(monkeypatch, quadric):
    if not quadric:
        monkeypatch.setitem(sys.modules, "fast_simplification", None)  # force the fallback
    else:
        pytest.importorskip("fast_simplification")
    mesh = _grid_mesh()
    small = mesh.decimated(0.2)
    assert 0.1 * mesh.num_faces < small.num_faces < 0.35 * mesh.num_faces
    assert small.shading == "vertex" and small.colors.shape == (len(small.vertices), 3)
    # geometry and colours stay where they were
    lo, hi = mesh.bounds
    assert np.all(small.bounds[0] >= lo - 1e-6) and np.all(small.bounds[1] <= hi + 1e-6)
    np.testing.assert_allclose(small.colors[:, 0], small.vertices[:, 0] - 1e6, atol=0.1)
    with pytest.raises(ValueError):
        mesh.decimated(0.0)


def test_scene_flattened_with_transforms():
    import trimesh

    box = trimesh.creation.box(extents=(1, 1, 1))
    scene = trimesh.Scene()
    scene.add_geometry(box, transform=trimesh.transformations.translation_matrix([10, 0, 0]))
    scene.add_geometry(box, transform=trimesh.transformations.translation_matrix([-10, 0, 0]))
    mesh = mesh_from_trimesh(scene)
    assert mesh.num_faces == 24
    np.testing.assert_allclose(mesh.bounds, [[-10.5, -0.5, -0.5], [10.5, 0.5, 0.5]])
    np.testing.assert_allclose(mesh.offset, 0.0, atol=1e-12)


def test_shading_requests(tmp_path):
    import trimesh

    plain = trimesh.creation.box()
    assert mesh_from_trimesh(plain).shading == "shaded"
    with pytest.raises(ValueError):
        mesh_from_trimesh(plain, shading="vertex")
    with pytest.raises(ValueError):
        mesh_from_trimesh(plain, shading="texture")
    with pytest.raises(ValueError):
        mesh_from_trimesh(plain, shading="pretty")
    coloured = trimesh.creation.box()
    coloured.visual.vertex_colors = np.tile([255, 0, 0, 255], (len(coloured.vertices), 1))
    m = mesh_from_trimesh(coloured)
    assert m.shading == "vertex"
    np.testing.assert_allclose(m.colors, np.tile([1, 0, 0], (len(m.vertices), 1)))
    assert mesh_from_trimesh(coloured, shading="shaded").shading == "shaded"
    faces = trimesh.creation.box()
    faces.visual.face_colors = np.tile([0, 255, 0, 255], (len(faces.faces), 1))
    assert mesh_from_trimesh(faces).shading == "vertex"
    with pytest.raises(FileNotFoundError):
        load_mesh(tmp_path / "missing.ply")
