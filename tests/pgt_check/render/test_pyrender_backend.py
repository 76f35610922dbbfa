"""The pyrender backend against the moderngl reference and against exact projection.

Tolerances (measured values in brackets, sample scene 320x240 and the generated meshes):
coverage masks agree on >= 99.5 % of pixels [100 %]; depth on pixels both cover: median
relative difference < 1e-4 [2e-5; 24-bit depth buffer, near_ratio 1e-3] and 99th percentile
< 1e-3; colour (pyrender reads back 8 bit): median |diff| <= 1/255 and 99th percentile <= 2/255
[0 and 1/255]; a known 3D point projects within 0.5 px of its OpenCV projection [exact].
"""

from __future__ import annotations

import gc
from pathlib import Path

import numpy as np
import pytest

try:
    from pgt_check.render.pyrender_backend import PyrenderRenderer, import_pyrender

    import_pyrender()
except ImportError as exc:  # the optional [pyrender] extra is not installed
    pytest.skip(
        f"pyrender not importable ({exc}); install: pip install pyrender==0.1.45 && "
        "pip install 'PyOpenGL>=3.1.7'",
        allow_module_level=True,
    )

from pgt_check.geometry.transforms import axis_angle_to_rotmat, make_rigid
from pgt_check.io import read_trajectory
from pgt_check.render import MeshData, Render, load_mesh, make_renderer
from pgt_check.types import Camera

# off-centre principal point, non-square pixels, odd width (row alignment of 8-bit RGB read-back)
CAM = Camera.pinhole(97, 72, 80.0, 95.0, 41.3, 30.7)
SAMPLE = Path(__file__).resolve().parents[3] / "sample_data" / "scene"

COVERAGE_AGREE = 0.995
DEPTH_MEDIAN_REL = 1e-4
DEPTH_P99_REL = 1e-3
COLOUR_MEDIAN = 1.0 / 255
COLOUR_P99 = 2.0 / 255 + 1e-6


@pytest.fixture
def factory():
    made = []

    def make(mesh, backend="pyrender", **kw):
        r = make_renderer(mesh, backend=backend, **kw)
        made.append(r)
        return r

    yield make
    for r in made:
        r.close()


def _agreement(a: Render, b: Render) -> dict[str, float]:
    """Cross-backend statistics on the pixels both renders cover."""
    both = a.coverage & b.coverage
    rel = np.abs(a.depth[both] - b.depth[both]) / a.depth[both]
    col = np.abs(a.rgb[both] - b.rgb[both])
    return {
        "coverage_agree": float((a.coverage == b.coverage).mean()),
        "both": float(both.mean()),
        "depth_median": float(np.median(rel)),
        "depth_p99": float(np.percentile(rel, 99)),
        "colour_median": float(np.median(col)),
        "colour_p99": float(np.percentile(col, 99)),
    }


def _assert_agree(stats: dict[str, float]) -> None:
    assert stats["coverage_agree"] >= COVERAGE_AGREE, stats
    assert stats["depth_median"] < DEPTH_MEDIAN_REL, stats
    assert stats["depth_p99"] < DEPTH_P99_REL, stats
    assert stats["colour_median"] <= COLOUR_MEDIAN, stats
    assert stats["colour_p99"] <= COLOUR_P99, stats


def _square_on_point(x_world: np.ndarray, rot: np.ndarray, half: float) -> MeshData:
    """A square in the camera's fronto-parallel plane centred on ``x_world``."""
    d = np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], dtype=float) * half
    v = x_world + d @ rot.T
    return MeshData(
        vertices=v,
        faces=[[0, 1, 2], [0, 2, 3]],
        shading="vertex",
        colors=np.ones((4, 3)),
        offset=v.mean(0),
    )


def _centroid(mask: np.ndarray) -> np.ndarray:
    rows, cols = np.nonzero(mask)
    return np.array([cols.mean(), rows.mean()])


def _bumpy_mesh(seed: int = 0, n: int = 24) -> MeshData:
    """A coloured height field (z = 3 + bumps) with random vertex colours, both windings."""
    rng = np.random.default_rng(seed)
    xs = np.linspace(-2.0, 2.0, n)
    gx, gy = np.meshgrid(xs, xs)
    gz = 3.0 + 0.3 * np.sin(2.0 * gx) * np.cos(1.5 * gy) + rng.normal(0, 0.02, gx.shape)
    v = np.stack([gx, gy, gz], -1).reshape(-1, 3)
    idx = np.arange(n * n).reshape(n, n)
    a, b, c, d = idx[:-1, :-1], idx[:-1, 1:], idx[1:, :-1], idx[1:, 1:]
    faces = np.concatenate(
        [np.stack([a, b, d], -1).reshape(-1, 3), np.stack([a, c, d], -1).reshape(-1, 3)]
    )
    return MeshData(
        vertices=v,
        faces=faces,
        shading="vertex",
        colors=rng.uniform(0, 1, (len(v), 3)),
        offset=0.5 * (v.min(0) + v.max(0)),
    )


# -- exact projection ---------------------------------------------------------------------------


def test_make_renderer_selects_pyrender():
    mesh = _bumpy_mesh()
    r = make_renderer(mesh, backend="pyrender")
    try:
        assert isinstance(r, PyrenderRenderer) and r.shading == "vertex"
    finally:
        r.close()
    with pytest.raises(ValueError):
        PyrenderRenderer(mesh, ambient=1.5)


@pytest.mark.parametrize("z", [1e-3, 2.0, 1e4])
def test_point_projects_within_half_pixel(factory, z):
    rot = axis_angle_to_rotmat(np.array([0.3, 1.0, 0.2]), 12.0)
    world_from_cam = make_rigid(rot, np.array([0.4, -0.2, 1.5]) * z + [3e5, -2e5, 100.0])
    x_cam = np.array([0.07, -0.05, 1.0]) * z
    x_world = rot @ x_cam + world_from_cam[:3, 3]
    mesh = _square_on_point(x_world, rot, 3.0 * z / 80.0)
    r = factory(mesh).render(CAM, world_from_cam)
    uvw = CAM.K @ x_cam
    expected = uvw[:2] / uvw[2]
    assert r.coverage.sum() > 10
    np.testing.assert_allclose(_centroid(r.coverage), expected, atol=0.5)
    np.testing.assert_allclose(r.depth[r.coverage], z, rtol=1e-4)
    # and the same pixels as the moderngl reference
    ref = factory(mesh, backend="moderngl").render(CAM, world_from_cam)
    np.testing.assert_array_equal(r.coverage, ref.coverage)


def test_depth_is_metric_z_on_slanted_plane(factory):
    xs = np.array([-3.0, 3.0])
    v = np.array([[x, y, 2.0 + 0.5 * x] for y in xs for x in xs])
    mesh = MeshData(
        vertices=v, faces=[[0, 1, 3], [0, 3, 2]], shading="vertex", colors=np.ones((4, 3))
    )
    r = factory(mesh).render(CAM, np.eye(4))
    assert r.coverage.all()
    fx, _ = CAM.focal
    cx, _ = CAM.principal_point
    u = np.arange(CAM.width)[None, :]
    expected = 2.0 / (1.0 - 0.5 * (u - cx) / fx) * np.ones((CAM.height, 1))
    # a sub-pixel shift (e.g. from 4x MSAA) would show here: d(depth)/du is ~6e-3 per px
    np.testing.assert_allclose(r.depth, expected, rtol=1e-5)


def test_msaa_off_by_default_no_blended_edges(factory):
    rot = np.eye(3)
    mesh = _square_on_point(np.array([0.05, -0.02, 2.0]), rot, 0.31)
    exact = factory(mesh).render(CAM, np.eye(4))
    assert set(np.unique(exact.rgb).tolist()) == {0.0, 1.0}  # hard edges, pure white
    blended = factory(mesh, msaa=True).render(CAM, np.eye(4))
    assert len(np.unique(blended.rgb)) > 2  # the switch does something


# -- against moderngl ------------------------------------------------------------------------


@pytest.mark.parametrize("shaded", [False, True])
def test_generated_mesh_matches_moderngl(factory, shaded):
    mesh = _bumpy_mesh(seed=3)
    if shaded:
        mesh = mesh.without_colour()
    rot = axis_angle_to_rotmat(np.array([1.0, -0.4, 0.2]), 8.0)
    pose = make_rigid(rot, [0.2, -0.1, -0.3])
    a = factory(mesh, backend="moderngl").render(CAM, pose)
    b = factory(mesh).render(CAM, pose)
    assert b.shading == a.shading == ("shaded" if shaded else "vertex")
    stats = _agreement(a, b)
    assert stats["both"] > 0.5
    _assert_agree(stats)


def test_head_light_formula(factory):
    # a plane tilted by 50 degrees about y: grey = ambient + (1 - ambient) |n . ray|
    rot = axis_angle_to_rotmat(np.array([0.0, 1.0, 0.0]), 50.0)
    d = np.array([[-2, -2, 0], [2, -2, 0], [2, 2, 0], [-2, 2, 0]], dtype=float)
    v = d @ rot.T + [0, 0, 4.0]
    mesh = MeshData(vertices=v, faces=[[0, 1, 2], [0, 3, 2]], shading="shaded")
    r = factory(mesh, ambient=0.3).render(CAM, np.eye(4))
    assert r.shading == "shaded"
    for u, row in [(48, 36), (35, 20), (80, 60)]:
        assert r.coverage[row, u]
        ray = np.linalg.solve(CAM.K, [u, row, 1.0])
        expected = 0.3 + 0.7 * abs(rot[:, 2] @ ray) / np.linalg.norm(ray)
        np.testing.assert_allclose(r.rgb[row, u], expected, atol=1.0 / 255)


def test_texture_odd_width_texels(factory, tmp_path):
    # 51 px wide texture: RGB rows are not 4-byte aligned; the quad fills the image exactly
    import trimesh
    from PIL import Image

    rng = np.random.default_rng(0)
    cells = rng.integers(0, 256, size=(3, 3, 3), dtype=np.uint8)
    image = np.kron(cells, np.ones((17, 17, 1), dtype=np.uint8))
    v = np.array([[-1, 1, 2], [1, 1, 2], [1, -1, 2], [-1, -1, 2]], dtype=float)
    uv = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], dtype=float)
    material = trimesh.visual.material.PBRMaterial(baseColorTexture=Image.fromarray(image))
    tm = trimesh.Trimesh(
        v,
        [[0, 1, 2], [0, 2, 3]],
        process=False,
        visual=trimesh.visual.TextureVisuals(uv=uv, material=material),
    )
    tm.export(tmp_path / "quad.glb")
    mesh = load_mesh(tmp_path / "quad.glb")
    assert mesh.shading == "texture"
    cam = Camera.pinhole(51, 51, 51.0, 51.0, 25.0, 25.0)
    r = factory(mesh).render(cam, np.eye(4))
    ref = factory(mesh, backend="moderngl").render(cam, np.eye(4))
    assert r.shading == "texture" and r.coverage.all()
    for i in range(3):
        for j in range(3):
            got = r.rgb[17 * i + 8, 17 * j + 8] * 255
            np.testing.assert_allclose(got, cells[i, j], atol=2)
    _assert_agree(_agreement(ref, r))


@pytest.mark.parametrize("shading", ["auto", "shaded"])
def test_sample_scene_matches_moderngl(factory, shading):
    if not (SAMPLE / "mesh.glb").is_file():
        pytest.skip("sample_data/scene not generated")
    traj = read_trajectory(SAMPLE / "trajectories.txt")
    mesh = load_mesh(SAMPLE / "mesh.glb", shading=shading)
    assert mesh.shading == ("texture" if shading == "auto" else "shaded")
    a, b = factory(mesh, backend="moderngl"), factory(mesh)
    for frame in traj.frames[::8]:
        ra = a.render(frame.camera, frame.world_from_cam)
        rb = b.render(frame.camera, frame.world_from_cam)
        assert rb.shading == mesh.shading
        _assert_agree(_agreement(ra, rb))


@pytest.mark.shared_data
def test_7scenes_mesh_matches_moderngl(shared_data, factory):
    root = shared_data / "7scenes_redkitchen"
    traj = read_trajectory(root / "trajectories.txt")
    mesh = load_mesh(root / "mesh.ply")
    a, b = factory(mesh, backend="moderngl"), factory(mesh)
    for frame in traj.frames[::50]:
        cam = frame.camera.scaled(0.25)
        ra, rb = a.render(cam, frame.world_from_cam), b.render(cam, frame.world_from_cam)
        stats = _agreement(ra, rb)
        assert stats["both"] > 0.3
        _assert_agree(stats)


# -- life cycle ------------------------------------------------------------------------------


def test_close_and_garbage_collection_leave_other_contexts_alone(factory):
    # pyrender's own delete()/__del__ call eglTerminate on the shared display, which killed
    # every other EGL context of the process (moderngl then rendered garbage)
    mesh = _bumpy_mesh(seed=1)
    pose = make_rigid(np.eye(3), [0.0, 0.0, -0.5])
    mgl = factory(mesh, backend="moderngl")
    first = mgl.render(CAM, pose)
    keep = factory(mesh)
    kept = keep.render(CAM, pose)
    for close in (True, False):
        tmp = make_renderer(mesh, backend="pyrender")
        tmp.render(CAM, pose)
        if close:
            tmp.close()
            tmp.close()  # idempotent
        del tmp
        gc.collect()
        again = mgl.render(CAM, pose)
        np.testing.assert_array_equal(again.rgb, first.rgb)
        np.testing.assert_array_equal(again.depth, first.depth)
        np.testing.assert_array_equal(keep.render(CAM, pose).depth, kept.depth)


def test_resize_empty_view_and_reopen(factory):
    mesh = _square_on_point(np.array([0.0, 0.0, 2.0]), np.eye(3), 0.3)
    r = factory(mesh)
    for w, h in [(32, 24), (51, 70), (32, 24)]:
        out = r.render(Camera.pinhole(w, h, 40, 40, (w - 1) / 2, (h - 1) / 2), np.eye(4))
        assert out.rgb.shape == (h, w, 3) and out.depth.shape == (h, w) and out.coverage.any()
        assert out.rgb.dtype == np.float32 and out.depth.dtype == np.float32
    away = make_rigid(axis_angle_to_rotmat(np.array([0.0, 1.0, 0.0]), 180.0), np.zeros(3))
    empty = r.render(CAM, away)
    assert not empty.coverage.any() and empty.rgb.shape == (72, 97, 3)
    r.close()
    assert r.render(CAM, np.eye(4)).coverage.any()  # a closed renderer starts a new context
    with pytest.raises(ValueError):
        r.render(CAM, np.eye(3))
