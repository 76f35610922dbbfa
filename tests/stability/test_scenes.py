"""End-to-end stability cases on procedural scenes (stage 1 + 2 of the runner).

Each test's docstring states its expected outcome. ``Scene.check`` (stab_scenes.py) also asserts
for every record: no internal_error, no NaN/inf float, PASS only under the threshold, and an
UNVERIFIABLE always with a reason.
"""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from stab_scenes import (
    CAM,
    box_mesh,
    box_room_mesh,
    checker_texture,
    degrade,
    look_at,
    noise_texture,
    plane_mesh,
)

from pgt_check.geometry.transforms import axis_angle_to_rotmat, make_rigid
from pgt_check.render import mesh_from_trimesh
from pgt_check.types import Camera

#: a view of the +y wall of the 4 m room from inside, slightly oblique
ROOM_POSE = look_at([0.3, -1.0, 0.2], [0.0, 2.0, -0.1])


def rotated(pose: np.ndarray, deg: float, axis=(0.0, 1.0, 0.0)) -> np.ndarray:
    """pose @ R(axis, deg): a rotation error in the camera frame."""
    return pose @ make_rigid(axis_angle_to_rotmat(np.array(axis), deg), np.zeros(3))


def translated(pose: np.ndarray, t) -> np.ndarray:
    """pose @ [I | t]: a translation error in the camera frame (metres)."""
    return pose @ make_rigid(np.eye(3), np.asarray(t, dtype=float))


def verdicts(recs) -> list[str]:
    return [r["verdict"] for r in recs]


# -- baseline ------------------------------------------------------------------------------------
def test_room_correct_pass_and_rotation_fail(scene_factory, room_mesh):
    """Textured room: the correct pose PASSes with ~0 px; a 5 deg yaw error FAILs."""
    s = scene_factory(room_mesh)
    good = s.frame(CAM, ROOM_POSE)
    bad = s.frame(CAM, ROOM_POSE, rotated(ROOM_POSE, 5.0))
    a, b = s.check([good, bad])
    assert a["verdict"] == "PASS" and a["corner_error_px"] < 1.0
    assert b["verdict"] == "FAIL" and b["corner_error_px"] > 10.0


# -- georeferenced coordinates -------------------------------------------------------------------
@pytest.mark.parametrize("offset", [(1e5, -3e6, 1e7), (-4.5e6, 5.4e6, 300.0), (7e6, 7e6, -7e6)])
def test_georeferenced_matches_origin(scene_factory, offset):
    """Mesh and poses shifted by up to 1e7 m (float64): renders equal the origin case to float32
    rounding of colours (no jitter) and verdicts / corner errors are the same."""
    offset = np.asarray(offset, dtype=np.float64)
    parts = box_room_mesh(textured=True, seed=3)
    from dataclasses import replace

    shifted = replace(parts, vertices=parts.vertices + offset, offset=parts.offset + offset)
    base = scene_factory(parts)
    geo = scene_factory(shifted)
    shift = make_rigid(np.eye(3), offset)
    for pose in (ROOM_POSE, rotated(ROOM_POSE, 20.0, (0.0, 0.0, 1.0))):
        r0 = base.render(CAM, pose)
        r1 = geo.render(CAM, shift @ pose)
        assert (r0.coverage != r1.coverage).sum() == 0
        assert float(np.abs(r0.rgb - r1.rgb).max()) < 1e-5
        assert float(np.abs(r0.depth - r1.depth).max()) < 1e-5
    frames0 = [
        base.frame(CAM, ROOM_POSE, frame_id="g0"),
        base.frame(CAM, ROOM_POSE, rotated(ROOM_POSE, 5.0), frame_id="g1"),
    ]
    frames1 = [f.with_pose(shift @ f.world_from_cam) for f in frames0]
    recs0, recs1 = base.check(frames0), geo.check(frames1)
    assert verdicts(recs0) == verdicts(recs1) == ["PASS", "FAIL"]
    for a, b in zip(recs0, recs1, strict=True):
        assert b["corner_error_px"] == pytest.approx(a["corner_error_px"], abs=1e-3)


# -- empty / tiny coverage -----------------------------------------------------------------------
def test_facing_away_sky_and_grazing_are_low_coverage(scene_factory):
    """A ground plane (z = 0) seen from above is fine; the same camera facing away, looking at
    the sky, or seeing a sliver at the horizon -> UNVERIFIABLE low_coverage (photos are real
    views, the stored pose sees nothing)."""
    s = scene_factory(plane_mesh(noise_texture(5), half=3.0))
    down = look_at([0.2, 0.1, 2.0], [0.0, 0.0, 0.0], up=(0.0, 1.0, 0.0))
    up = look_at([0.2, 0.1, 2.0], [0.0, 0.0, 10.0], up=(0.0, 1.0, 0.0))
    horizon = look_at([0.0, -2.9, 0.05], [0.0, 50.0, 21.79])  # pitched up 23.5 deg
    frames = [
        s.frame(CAM, down),
        s.frame(CAM, down, rotated(down, 180.0)),  # facing away
        s.frame(CAM, down, up),  # sky only
        s.frame(CAM, down, horizon),  # grazing sliver
    ]
    recs = s.check(frames)
    assert recs[0]["verdict"] == "PASS"
    for r in recs[1:]:
        assert (r["verdict"], r["reason"]) == ("UNVERIFIABLE", "low_coverage"), r["coverage"]
    assert recs[1]["coverage"] == 0.0 and recs[2]["coverage"] == 0.0
    assert recs[3]["coverage"] < 0.05


def test_camera_inside_object(scene_factory):
    """Stored pose inside a solid box in front of the textured room while the photo was taken
    from outside it: the render shows the box's inner faces -> FAIL or UNVERIFIABLE, never
    PASS. A camera inside the closed room itself (the usual case) PASSes."""
    room = box_room_mesh(seed=10)
    tm = trimesh.Scene([*box_mesh([0.0, 0.5, 0.0], 0.6, seed=40)])
    obj = mesh_from_trimesh(tm)
    from dataclasses import replace

    both = replace(
        room,
        vertices=np.vstack([room.vertices, obj.vertices]),
        faces=np.vstack([room.faces, obj.faces + len(room.vertices)]),
        uv=np.vstack([room.uv, obj.uv]),
        textures=room.textures + obj.textures,
        face_texture=np.concatenate([room.face_texture, obj.face_texture + len(room.textures)]),
        colors=np.vstack([room.colors, obj.colors]),
    )
    s = scene_factory(both)
    outside = look_at([0.0, -1.5, 0.3], [0.0, 0.5, 0.0])
    inside = look_at([0.0, 0.5, 0.0], [0.0, 2.0, 0.0])
    recs = s.check([s.frame(CAM, outside), s.frame(CAM, outside, inside)])
    assert recs[0]["verdict"] == "PASS"
    assert recs[1]["verdict"] != "PASS"


# -- depth range -----------------------------------------------------------------------------
@pytest.mark.parametrize("scale", [1e-3, 1.0, 1e4])
def test_near_and_far_geometry(scene_factory, scale):
    """The room scaled so the camera is 1e-3 .. 1e4 m from the walls: the correct pose PASSes,
    a 5 deg error FAILs (clip planes follow the mesh bounds, depth is metric float32)."""
    from dataclasses import replace

    m = box_room_mesh(seed=20)
    m = replace(m, vertices=m.vertices * scale, offset=m.offset * scale)
    pose = ROOM_POSE.copy()
    pose[:3, 3] *= scale
    s = scene_factory(m)
    r = s.render(CAM, pose)
    d = r.depth[r.coverage]
    assert r.coverage.all() and 0.5 * scale < d.min() and d.max() < 5 * scale
    recs = s.check([s.frame(CAM, pose), s.frame(CAM, pose, rotated(pose, 5.0))])
    assert verdicts(recs) == ["PASS", "FAIL"]


def test_near_object_with_far_background(scene_factory):
    """A 1 cm textured card 2 cm in front of the camera and a 2e4 m wide wall 1e4 m away
    (depth ratio 5e5). Known limitation (docs in tests/stability/README.md): the renderer keeps
    znear >= 1e-4 * zfar for depth-test resolution, so the card (2 cm < 1 m) is clipped from the
    render, while the "photo" (wall render + card-only render composited) shows it; lowering
    near_ratio to 1e-6 instead loses the far wall (float32 projection / depth precision). Expected: no crash, no
    NaN; the correct pose PASSes on the wall around the card (or is UNVERIFIABLE), a 5 deg error
    is never PASS."""
    from dataclasses import replace

    from pgt_check.render import make_renderer

    far = plane_mesh(noise_texture(30), half=1e4, z=1e4)
    card = plane_mesh(noise_texture(31), half=5e-3, z=2e-2)
    both = replace(
        far,
        vertices=np.vstack([far.vertices, card.vertices]),
        faces=np.vstack([far.faces, card.faces + len(far.vertices)]),
        uv=np.vstack([far.uv, card.uv]),
        textures=far.textures + card.textures,
        face_texture=np.concatenate([far.face_texture, card.face_texture + 1]),
        colors=np.vstack([far.colors, card.colors]),
    )
    pose = make_rigid(np.eye(3), [1e-3, 0.0, 0.0])  # looking down +z at both
    s = scene_factory(both)
    r = s.render(CAM, pose)
    assert r.coverage.all() and float(r.depth.min()) > 1.0  # the card is clipped
    card_only = make_renderer(card)  # the card alone gets tight clip planes
    try:
        c = card_only.render(CAM, pose)
    finally:
        card_only.close()
    assert 0.03 < c.coverage.mean() < 0.5  # the photo shows the card ...
    assert float(c.depth[c.coverage].min()) == pytest.approx(2e-2, rel=1e-3)
    composite = np.where(c.coverage[:, :, None], c.rgb, r.rgb)  # ... in front of the wall
    photo = type(r)(composite, r.depth, r.coverage, r.shading)
    recs = s.check(
        [
            s.frame(CAM, pose, photo=lambda _: photo.rgb),
            s.frame(CAM, pose, rotated(pose, 5.0), photo=lambda _: photo.rgb),
        ]
    )
    assert recs[0]["verdict"] in ("PASS", "UNVERIFIABLE")
    assert recs[1]["verdict"] in ("FAIL", "UNVERIFIABLE")


# -- intrinsics and image size ----------------------------------------------------------------
@pytest.mark.parametrize(
    "camera, expect_good",
    [
        (Camera.pinhole(240, 180, 30.0, 30.0, 119.5, 89.5), ("PASS",)),  # ~152 deg wide
        (Camera.pinhole(240, 180, 3000.0, 3000.0, 119.5, 89.5), ("PASS",)),  # 4.6 deg tele
        (Camera.pinhole(240, 180, 200.0, 200.0, -150.0, 89.5), ("PASS",)),  # pp left of image
        (Camera.pinhole(240, 180, 200.0, 200.0, 119.5, 600.0), ("PASS",)),  # pp far below
        (Camera.pinhole(240, 180, 200.0, 600.0, 119.5, 89.5), ("PASS",)),  # fx != fy
        (Camera.pinhole(240, 180, 1e-3, 1e-3, 119.5, 89.5), ("PASS", "UNVERIFIABLE")),
        (Camera.pinhole(240, 180, 1e6, 1e6, 119.5, 89.5), ("PASS", "UNVERIFIABLE")),
    ],
    ids=["wide", "tele", "pp-left", "pp-below", "anamorphic", "f=1e-3", "f=1e6"],
)
def test_extreme_intrinsics(scene_factory, room_mesh, camera, expect_good):
    """Extreme focal lengths and principal points off the image: the correct pose gives the
    listed verdicts (PASS wherever the view is matchable; a degenerate f=1e-3 / 1e6 view may be
    UNVERIFIABLE), a 5 deg yaw error is never PASS."""
    s = scene_factory(room_mesh)
    pose = look_at([0.0, -1.0, 0.0], [0.0, 2.0, 0.0])
    deg = 5.0 if camera.focal[0] >= 30 else 60.0  # 5 deg is sub-pixel at f = 1e-3
    recs = s.check([s.frame(camera, pose), s.frame(camera, pose, rotated(pose, deg))])
    assert recs[0]["verdict"] in expect_good, recs[0]["reason"]
    assert recs[1]["verdict"] != "PASS" or camera.focal[0] < 1, recs[1]


def test_tiny_image(scene_factory, room_mesh):
    """A 32x24 photo (threshold 0.8 px): the correct pose may still PASS (17 exact matches on an
    identical render) or be UNVERIFIABLE; a 5 deg error (~3 px) never PASSes; an UNVERIFIABLE
    carries a matching-stage reason."""
    s = scene_factory(room_mesh)
    cam = CAM.scaled(32 / 240)
    assert (cam.width, cam.height) == (32, 24)
    recs = s.check([s.frame(cam, ROOM_POSE), s.frame(cam, ROOM_POSE, rotated(ROOM_POSE, 5.0))])
    assert recs[0]["verdict"] in ("PASS", "UNVERIFIABLE")
    assert recs[1]["verdict"] in ("FAIL", "UNVERIFIABLE")
    for r in recs:
        if r["verdict"] == "UNVERIFIABLE":
            assert r["reason"] in ("too_few_matches", "too_few_inliers", "degenerate_matches")


def test_large_photo_end_to_end(scene_factory, sample_scene):
    """A 4000x3000 photo of the sample scene (camera scaled 12.5x) is rendered and matched at
    resize_max (320): the correct pose PASSes, a perturbed one FAILs; errors are reported in
    4000 px units (threshold = 2 % of the 5000 px diagonal = 100 px)."""
    from pgt_check.io import read_trajectory
    from pgt_check.render import load_mesh

    traj = read_trajectory(sample_scene / "trajectories.txt", "auto")
    s = scene_factory(load_mesh(sample_scene / "mesh.glb"))
    f0 = traj.frames[0]
    big = f0.camera.scaled(12.5)
    assert (big.width, big.height) == (4000, 3000)
    pose = f0.world_from_cam
    recs = s.check([s.frame(big, pose), s.frame(big, pose, rotated(pose, 4.0))])
    assert recs[0]["match_width"] == 320 and recs[0]["width"] == 4000
    assert recs[0]["threshold_px"] == pytest.approx(100.0)
    assert verdicts(recs) == ["PASS", "FAIL"]


# -- appearance ------------------------------------------------------------------------------
def test_textureless_room_is_unverifiable(scene_factory):
    """Plain grey walls: nothing to match -> UNVERIFIABLE (too_few_matches or similar), for
    the correct and for a wrong pose alike: no silent PASS."""
    s = scene_factory(box_room_mesh(textured=False))
    recs = s.check([s.frame(CAM, ROOM_POSE), s.frame(CAM, ROOM_POSE, rotated(ROOM_POSE, 5.0))])
    for r in recs:
        assert r["verdict"] == "UNVERIFIABLE"
        assert r["reason"] in ("too_few_matches", "too_few_inliers", "degenerate_matches")


def test_repetitive_checker(scene_factory):
    """A finite periodic checker wall: the correct pose is PASS or UNVERIFIABLE (ambiguous
    matches), a shift of half a checker square is never PASS."""
    s = scene_factory(plane_mesh(checker_texture(256, 8), half=1.0, z=0.0))
    pose = look_at([0.05, -0.2, 1.8], [0.0, 0.0, 0.0], up=(0.0, 1.0, 0.0))
    recs = s.check([s.frame(CAM, pose), s.frame(CAM, pose, translated(pose, [0.125, 0, 0]))])
    assert recs[0]["verdict"] in ("PASS", "UNVERIFIABLE")
    assert recs[1]["verdict"] in ("FAIL", "UNVERIFIABLE")


@pytest.mark.parametrize(
    "photo, grayscale",
    [
        (lambda x: degrade(x, gain=0.35, gamma=1.4, noise=0.01), False),  # under-exposed
        (lambda x: degrade(x, gain=2.2, gamma=0.8, noise=0.01), False),  # over-exposed
        (lambda x: degrade(x, noise=0.02), True),  # grayscale file
        (lambda x: 1.0 - x, False),  # inverted (negative): different appearance
    ],
    ids=["dark", "bright", "grayscale", "negative"],
)
def test_exposure_and_grayscale(scene_factory, room_mesh, photo, grayscale):
    """Strong exposure differences and a single-channel photo: correct pose PASSes (SIFT is
    gain/gamma invariant), a 5 deg error FAILs. The negative photo may not match at all:
    then UNVERIFIABLE, never PASS for the wrong pose."""
    s = scene_factory(room_mesh)
    recs = s.check(
        [
            s.frame(CAM, ROOM_POSE, photo=photo, grayscale=grayscale),
            s.frame(CAM, ROOM_POSE, rotated(ROOM_POSE, 5.0), photo=photo, grayscale=grayscale),
        ]
    )
    if photo(np.full((1, 1, 3), 0.9, np.float32))[0, 0, 0] < 0.2:  # negative
        assert recs[0]["verdict"] in ("PASS", "UNVERIFIABLE")
        assert recs[1]["verdict"] in ("FAIL", "UNVERIFIABLE")
    else:
        assert verdicts(recs) == ["PASS", "FAIL"]
