import numpy as np
import pytest

from pgt_check.enhance.reproject import reproject_reference
from pgt_check.io import load_image, read_trajectory
from pgt_check.render import load_mesh, make_renderer
from pgt_eval import perturb_pose


@pytest.fixture(scope="module")
def scene(sample_scene):
    traj = read_trajectory(sample_scene / "trajectories.txt")
    mesh = load_mesh(sample_scene / "mesh.glb")
    r = make_renderer(mesh)
    yield traj, r
    r.close()


def test_reprojecting_a_frame_onto_itself_reproduces_its_render(scene):
    traj, r = scene
    f = traj.frames[0]
    cam = f.camera
    rend = r.render(cam, f.world_from_cam)
    img, filled = reproject_reference(
        rend.rgb, rend.depth, cam, f.world_from_cam, rend.rgb, rend.depth, cam, f.world_from_cam
    )
    assert filled.sum() >= 0.95 * rend.coverage.sum()
    np.testing.assert_allclose(img[filled], rend.rgb[filled], atol=2e-3)


def test_reprojected_neighbour_matches_the_photo_better_than_nothing(scene):
    traj, r = scene
    f, ref = traj.frames[1], traj.frames[2]  # both unperturbed in sample_data
    cam = f.camera
    rend = r.render(cam, f.world_from_cam)
    ref_render = r.render(ref.camera, ref.world_from_cam)
    ref_photo = load_image(ref.image_file)
    img, filled = reproject_reference(
        rend.rgb, rend.depth, cam, f.world_from_cam, ref_photo, ref_render.depth, ref.camera,
        ref.world_from_cam,
    )
    photo = load_image(f.image_file)
    assert filled.mean() > 0.5
    # appearance comes from the photo: closer to this frame's photo than the plain render is
    err_reproj = np.abs(img - photo)[filled].mean()
    err_render = np.abs(rend.rgb - photo)[filled].mean()
    assert err_reproj < err_render


def test_geometry_stays_the_frames_own(scene):
    """With a wrong pose, the reprojected image is displaced like the render, not like the
    reference: a wrong pose must not look right."""
    traj, r = scene
    f, ref = traj.frames[1], traj.frames[2]
    cam = f.camera
    wrong = perturb_pose(f.world_from_cam, 4.0, 0.0, np.random.default_rng(0))
    rend = r.render(cam, wrong)
    ref_render = r.render(ref.camera, ref.world_from_cam)
    img, filled = reproject_reference(
        rend.rgb, rend.depth, cam, wrong, load_image(ref.image_file), ref_render.depth,
        ref.camera, ref.world_from_cam,
    )
    # coverage of the reprojected image equals the coverage of the *wrong* render
    assert not (filled & ~rend.coverage).any()


def test_shape_errors(scene):
    traj, r = scene
    f = traj.frames[0]
    rend = r.render(f.camera, f.world_from_cam)
    with pytest.raises(ValueError, match="render_rgb"):
        reproject_reference(rend.rgb[:10], rend.depth, f.camera, f.world_from_cam, rend.rgb,
                            rend.depth, f.camera, f.world_from_cam)
