from __future__ import annotations

import numpy as np
import pytest

from pgt_check.errors import ConfigError
from pgt_check.geometry.transforms import axis_angle_to_rotmat, make_rigid, quat_to_rotmat
from pgt_check.render import MeshData, load_mesh, make_renderer
from pgt_check.types import Camera

# off-centre principal point and non-square pixels
CAM = Camera.pinhole(96, 72, 80.0, 95.0, 41.3, 30.7)


def _look_from(centre: np.ndarray) -> np.ndarray:
    """world_from_cam with identity rotation at ``centre``."""
    return make_rigid(np.eye(3), centre)


def _tiny_quad(point: np.ndarray, half: float) -> MeshData:
    """A small axis-aligned square (2 triangles) centred at ``point`` facing -z."""
    d = np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], dtype=float) * half
    v = point + d
    return MeshData(
        vertices=v,
        faces=np.array([[0, 1, 2], [0, 2, 3]]),
        shading="vertex",
        colors=np.ones((4, 3)),
        offset=0.5 * (v.min(0) + v.max(0)),
    )


def _centroid(mask: np.ndarray) -> np.ndarray:
    rows, cols = np.nonzero(mask)
    return np.array([cols.mean(), rows.mean()])


@pytest.fixture
def renderer_factory():
    made = []

    def make(mesh, **kw):
        r = make_renderer(mesh, **kw)
        made.append(r)
        return r

    yield make
    for r in made:
        r.close()


@pytest.mark.parametrize("z", [1e-3, 2.0, 1e4])
def test_point_projects_within_half_pixel(renderer_factory, z):
    # a known world point, seen from a rotated camera; the rendered square is centred on it
    rot = axis_angle_to_rotmat(np.array([0.3, 1.0, 0.2]), 12.0)
    world_from_cam = make_rigid(rot, np.array([0.4, -0.2, 1.5]) * z)
    x_cam = np.array([0.07, -0.05, 1.0]) * z
    x_world = rot @ x_cam + world_from_cam[:3, 3]
    # square in the camera's fronto-parallel plane: its image centroid is the projected centre
    half = 3.0 * z / 80.0
    d = np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], dtype=float) * half
    v = x_world + d @ rot.T
    mesh = MeshData(
        vertices=v,
        faces=[[0, 1, 2], [0, 2, 3]],
        shading="vertex",
        colors=np.ones((4, 3)),
        offset=v.mean(0),
    )
    r = renderer_factory(mesh).render(CAM, world_from_cam)
    uvw = CAM.K @ x_cam
    expected = uvw[:2] / uvw[2]
    assert r.coverage.sum() > 10
    np.testing.assert_allclose(_centroid(r.coverage), expected, atol=0.5)
    np.testing.assert_allclose(r.depth[r.coverage], z, rtol=1e-4)


def test_depth_is_metric_z_on_slanted_plane(renderer_factory):
    # plane z = 2 + 0.5 x in camera coordinates; depth must equal metric z per pixel
    xs = np.array([-3.0, 3.0])
    ys = np.array([-3.0, 3.0])
    v = np.array([[x, y, 2.0 + 0.5 * x] for y in ys for x in xs])
    mesh = MeshData(
        vertices=v,
        faces=[[0, 1, 3], [0, 3, 2]],
        shading="vertex",
        colors=np.ones((4, 3)),
        offset=v.mean(0),
    )
    r = renderer_factory(mesh).render(CAM, np.eye(4))
    assert r.coverage.all()
    u = np.arange(CAM.width)[None, :]
    fx, _ = CAM.focal
    cx, _ = CAM.principal_point
    # z = 2 + 0.5 * x, x = (u - cx) / fx * z  =>  z = 2 / (1 - 0.5 (u - cx) / fx)
    expected = 2.0 / (1.0 - 0.5 * (u - cx) / fx) * np.ones((CAM.height, 1))
    np.testing.assert_allclose(r.depth, expected, rtol=1e-4)


def test_coverage_and_background(renderer_factory):
    mesh = _tiny_quad(np.array([0.0, 0.0, 2.0]), 0.3)
    r = renderer_factory(mesh).render(CAM, np.eye(4))
    fx, fy = CAM.focal
    cx, cy = CAM.principal_point
    u0, u1 = cx - 0.3 / 2 * fx, cx + 0.3 / 2 * fx
    v0, v1 = cy - 0.3 / 2 * fy, cy + 0.3 / 2 * fy
    uu, vv = np.meshgrid(np.arange(CAM.width), np.arange(CAM.height))
    inside = (uu > u0 + 0.5) & (uu < u1 - 0.5) & (vv > v0 + 0.5) & (vv < v1 - 0.5)
    outside = (uu < u0 - 0.5) | (uu > u1 + 0.5) | (vv < v0 - 0.5) | (vv > v1 + 0.5)
    assert r.coverage[inside].all() and not r.coverage[outside].any()
    assert np.all(r.rgb[~r.coverage] == 0) and np.all(r.depth[~r.coverage] == 0)
    np.testing.assert_allclose(r.rgb[r.coverage], 1.0)
    assert r.rgb.dtype == np.float32 and r.depth.dtype == np.float32 and r.coverage.dtype == bool
    assert r.rgb.shape == (CAM.height, CAM.width, 3)


def test_vertex_colours_interpolated(renderer_factory):
    v = np.array([[-1, -1, 2], [1, -1, 2], [1, 1, 2], [-1, 1, 2]], dtype=float) * [3, 3, 1]
    colors = np.array([[1, 0, 0], [1, 0, 0], [0, 0, 1], [0, 0, 1]], dtype=float)  # top red
    mesh = MeshData(vertices=v, faces=[[0, 1, 2], [0, 2, 3]], shading="vertex", colors=colors)
    r = renderer_factory(mesh).render(CAM, np.eye(4))
    # fronto-parallel plane at z = 2: red fraction is linear in y = (v - cy) / fy * 2
    _, fy = CAM.focal
    _, cy = CAM.principal_point
    y = (np.arange(CAM.height) - cy) / fy * 2.0
    expected_red = (3.0 - y) / 6.0  # y = -3 (image top) red, y = +3 blue
    column = r.rgb[:, CAM.width // 2]
    np.testing.assert_allclose(column[:, 0], expected_red, atol=2e-3)
    np.testing.assert_allclose(column[:, 2], 1.0 - expected_red, atol=2e-3)
    assert column[0, 0] > column[-1, 0]  # row 0 is the image top


def _checker_quad_mesh(tmp_path, fmt: str) -> tuple[MeshData, np.ndarray]:
    """A 2x2 m quad at z = 2 with a 4x4 checker of distinct colours; UV (0,0) at the bottom-left."""
    import trimesh
    from PIL import Image

    rng = np.random.default_rng(0)
    cells = rng.integers(0, 256, size=(4, 4, 3), dtype=np.uint8)
    image = np.kron(cells, np.ones((16, 16, 1), dtype=np.uint8))  # 64x64, row 0 = top
    v = np.array([[-1, 1, 2], [1, 1, 2], [1, -1, 2], [-1, -1, 2]], dtype=float)  # y down in cam
    uv = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], dtype=float)  # bottom-left, ..., top-left
    material = trimesh.visual.material.PBRMaterial(baseColorTexture=Image.fromarray(image))
    tm = trimesh.Trimesh(
        v,
        [[0, 1, 2], [0, 2, 3]],
        process=False,
        visual=trimesh.visual.TextureVisuals(uv=uv, material=material),
    )
    path = tmp_path / f"quad.{fmt}"
    tm.export(path)
    return load_mesh(path), cells


@pytest.mark.parametrize("fmt", ["glb", "obj"])
def test_texture_texels(renderer_factory, tmp_path, fmt):
    mesh, cells = _checker_quad_mesh(tmp_path, fmt)
    assert mesh.shading == "texture"
    # camera at the origin looking down +z; the quad spans x, y in [-1, 1] at z = 2
    cam = Camera.pinhole(64, 64, 64.0, 64.0, 31.5, 31.5)  # quad fills the image exactly
    r = renderer_factory(mesh).render(cam, np.eye(4))
    assert r.shading == "texture"
    for i in range(4):
        for j in range(4):
            got = r.rgb[16 * i + 8, 16 * j + 8] * 255
            np.testing.assert_allclose(got, cells[i, j], atol=3)


def test_shaded_varies_with_normal_angle(renderer_factory):
    # two squares: one facing the camera, one tilted by 60 degrees; opposite windings
    a = np.array([[-1.0, -0.5, 3], [-0.1, -0.5, 3], [-0.1, 0.5, 3], [-1.0, 0.5, 3]])
    rot = axis_angle_to_rotmat(np.array([0.0, 1.0, 0.0]), 60.0)
    b = np.array([[-0.45, -0.5, 0], [0.45, -0.5, 0], [0.45, 0.5, 0], [-0.45, 0.5, 0]]) @ rot.T + [
        0.55,
        0,
        3,
    ]
    v = np.vstack([a, b])
    mesh = MeshData(
        vertices=v,
        faces=[[0, 1, 2], [0, 2, 3], [4, 6, 5], [4, 7, 6]],
        shading="vertex",
        colors=np.ones((8, 3)),
    ).without_colour()
    r = renderer_factory(mesh, ambient=0.2).render(CAM, np.eye(4))
    assert r.shading == "shaded"

    def expected(u: int, v: int, normal: np.ndarray) -> float:
        ray = np.linalg.solve(CAM.K, [u, v, 1.0])
        return 0.2 + 0.8 * abs(normal @ ray) / np.linalg.norm(ray)

    left, right = r.rgb[36, 27], r.rgb[36, 56]
    assert np.all(left == left[0]) and np.all(right == right[0])  # grey
    assert left[0] == pytest.approx(expected(27, 36, np.array([0, 0, 1.0])), abs=2e-3)
    assert right[0] == pytest.approx(expected(56, 36, rot[:, 2]), abs=2e-3)
    assert right[0] < left[0] - 0.2


def test_large_offset_gives_same_render(renderer_factory):
    rng = np.random.default_rng(1)
    v = rng.uniform(-1, 1, size=(60, 3)) + [0, 0, 4]
    f = rng.integers(0, 60, size=(40, 3))
    colors = rng.uniform(0, 1, size=(60, 3))
    pose = make_rigid(axis_angle_to_rotmat(np.array([1.0, 0.5, 0]), 5.0), [0.1, -0.2, 0.3])
    shift = np.array([1e6, -2e6, 3e5])
    renders = []
    for s in (np.zeros(3), shift):
        vs = v + s
        mesh = MeshData(
            vertices=vs,
            faces=f,
            shading="vertex",
            colors=colors,
            offset=0.5 * (vs.min(0) + vs.max(0)),
        )
        p = pose.copy()
        p[:3, 3] += s
        renders.append(renderer_factory(mesh).render(CAM, p))
    a, b = renders
    assert a.coverage.sum() > 100
    assert (a.coverage != b.coverage).sum() <= 2
    both = a.coverage & b.coverage
    np.testing.assert_allclose(a.depth[both], b.depth[both], rtol=1e-5)
    np.testing.assert_allclose(a.rgb[both], b.rgb[both], atol=1e-3)


def test_load_mesh_recentres_georeferenced_coordinates(tmp_path):
    import trimesh

    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], dtype=float) + [4.5e6, 5.4e6, 300.0]
    trimesh.Trimesh(v, [[0, 1, 2]], process=False).export(tmp_path / "geo.ply")
    mesh = load_mesh(tmp_path / "geo.ply")
    np.testing.assert_allclose(mesh.offset, [4.5e6 + 0.5, 5.4e6 + 0.5, 300.0])
    assert mesh.shading == "shaded" and mesh.vertices.dtype == np.float64


def test_empty_view_facing_away(renderer_factory):
    mesh = _tiny_quad(np.array([0.0, 0.0, 2.0]), 0.3)
    away = make_rigid(axis_angle_to_rotmat(np.array([0.0, 1.0, 0.0]), 180.0), np.zeros(3))
    r = renderer_factory(mesh).render(CAM, away)
    assert not r.coverage.any() and r.coverage_fraction == 0.0
    assert r.rgb.shape == (72, 96, 3)
    # sideways: the box is in front (z > 0) but outside the frustum
    side = make_rigid(axis_angle_to_rotmat(np.array([0.0, 1.0, 0.0]), 80.0), np.zeros(3))
    assert not renderer_factory(mesh).render(CAM, side).coverage.any()


def test_framebuffer_resizes_per_camera(renderer_factory):
    """Sizes in turn (as a frame's matching, edge and reference renders) give the render a
    fresh renderer makes of that view alone, also where a kept framebuffer last held another
    view (nothing of it may remain); the framebuffers kept are bounded."""
    from pgt_check.render.moderngl_backend import MAX_FRAMEBUFFERS

    mesh = _tiny_quad(np.array([0.0, 0.0, 2.0]), 0.3)
    r = renderer_factory(mesh)
    aside = np.eye(4)
    aside[0, 3] = 0.45  # the quad seen in a corner: most of the image is background
    sizes = [(32, 24), (50, 70), (32, 24), (20, 20), (41, 33), (64, 48), (50, 70), (32, 24)]
    for i, (w, h) in enumerate(sizes):
        cam = Camera.pinhole(w, h, 40, 40, (w - 1) / 2, (h - 1) / 2)
        pose = aside if i % 3 == 2 else np.eye(4)
        out = r.render(cam, pose)
        assert out.rgb.shape == (h, w, 3) and out.coverage.any()
        want = renderer_factory(mesh).render(cam, pose)
        assert np.array_equal(out.rgb, want.rgb) and np.array_equal(out.depth, want.depth)
        assert len(r._fbos) <= MAX_FRAMEBUFFERS
    assert len(r._fbos) == MAX_FRAMEBUFFERS and list(r._fbos)[-1] == (32, 24)


def test_distorted_camera_renders_as_pinhole(renderer_factory):
    mesh = _tiny_quad(np.array([0.0, 0.0, 2.0]), 0.3)
    r = renderer_factory(mesh)
    dist = Camera("OPENCV", 96, 72, (80.0, 95.0, 41.3, 30.7, 0.1, -0.05, 0.0, 0.0))
    np.testing.assert_array_equal(
        r.render(dist, np.eye(4)).coverage, r.render(CAM, np.eye(4)).coverage
    )


def test_bad_inputs():
    mesh = _tiny_quad(np.array([0.0, 0.0, 2.0]), 0.3)
    with pytest.raises(ConfigError):
        make_renderer(mesh, backend="nope")
    with pytest.raises(ValueError):
        make_renderer(mesh).render(CAM, np.eye(3))
    with pytest.raises(ValueError):
        MeshData(vertices=np.zeros((3, 2)), faces=[[0, 1, 2]], shading="shaded")
    with pytest.raises(ValueError):
        MeshData(vertices=np.zeros((3, 3)), faces=[[0, 1, 3]], shading="shaded")
    with pytest.raises(ValueError):
        MeshData(vertices=np.zeros((3, 3)), faces=[[0, 1, 2]], shading="vertex")


# -- real data ---------------------------------------------------------------------------------


def _first_pose(path) -> np.ndarray:
    """First row of a LaMAR trajectories.txt -> world_from_cam (parsed here on purpose)."""
    for line in path.read_text().splitlines():
        if line.strip() and not line.startswith("#"):
            vals = [s.strip() for s in line.split(",")]
            q = np.array(vals[2:6], dtype=float)
            t = np.array(vals[6:9], dtype=float)
            return make_rigid(quat_to_rotmat(q), t)
    raise ValueError(f"no pose in {path}")


def _first_camera(path, scale: float = 1.0) -> Camera:
    for line in path.read_text().splitlines():
        if line.strip() and not line.startswith("#"):
            vals = [s.strip() for s in line.split(",")]
            w, h, fx, fy, cx, cy = (float(x) for x in vals[4:10])
            cam = Camera.pinhole(int(w), int(h), fx, fy, cx - 0.5, cy - 0.5)  # COLMAP -> OpenCV
            return cam.scaled(scale) if scale != 1.0 else cam
    raise ValueError(f"no camera in {path}")


@pytest.mark.shared_data
def test_real_7scenes_mesh(shared_data, renderer_factory):
    root = shared_data / "7scenes_redkitchen"
    mesh = load_mesh(root / "mesh.ply")
    assert mesh.shading == "vertex"
    cam = _first_camera(root / "sensors.txt", 0.25)
    r = renderer_factory(mesh).render(cam, _first_pose(root / "trajectories.txt"))
    assert r.coverage_fraction > 0.5
    d = r.depth[r.coverage]
    assert 0.3 < np.percentile(d, 1) and np.percentile(d, 99) < 5.0
    assert r.rgb[r.coverage].std() > 0.05  # coloured, not flat


@pytest.mark.shared_data
def test_real_castle_mesh_shaded(shared_data, renderer_factory):
    root = shared_data / "sceaux_castle"
    mesh = load_mesh(root / "mesh.ply")
    assert mesh.shading == "shaded"
    cam = _first_camera(root / "sensors.txt", 0.1)
    r = renderer_factory(mesh).render(cam, _first_pose(root / "trajectories.txt"))
    assert r.shading == "shaded" and r.coverage_fraction > 0.3
    grey = r.rgb[r.coverage]
    np.testing.assert_array_equal(grey[:, 0], grey[:, 1])
    assert grey[:, 0].std() > 0.03  # shading shows structure


def test_interleaved_renderers_in_one_process(renderer_factory):
    # each renderer owns a GL context; using one must not disturb the other
    white = _tiny_quad(np.array([0.0, 0.0, 2.0]), 0.3)
    v = white.vertices + [0.2, 0.1, 0.0]
    red = MeshData(
        vertices=v, faces=white.faces, shading="vertex", colors=np.tile([1.0, 0, 0], (4, 1))
    )
    a = renderer_factory(white)
    first = a.render(CAM, np.eye(4))
    b = renderer_factory(red)
    for _ in range(2):
        again = a.render(CAM, np.eye(4))
        other = b.render(CAM, np.eye(4))
        np.testing.assert_array_equal(again.rgb, first.rgb)
        np.testing.assert_array_equal(again.depth, first.depth)
        assert other.coverage.any() and np.all(other.rgb[other.coverage] == [1, 0, 0])
    a.close()
    a.close()  # idempotent
    assert b.render(CAM, np.eye(4)).coverage.any()


def test_sample_scene_renders_textured(renderer_factory):
    from pathlib import Path

    root = Path(__file__).resolve().parents[3] / "sample_data" / "scene"
    if not (root / "mesh.glb").is_file():
        pytest.skip("sample_data/scene not generated")
    mesh = load_mesh(root / "mesh.glb")
    assert mesh.shading == "texture" and len(mesh.textures) > 5
    cam = _first_camera(root / "sensors.txt")
    r = renderer_factory(mesh).render(cam, _first_pose(root / "trajectories.txt"))
    assert r.coverage.all() and r.rgb.std() > 0.1
    assert 0.3 < r.depth.min() and r.depth.max() < 10.0
