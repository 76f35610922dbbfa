"""Generate sample_data/scene: a small procedural textured room with a camera trajectory.

Deterministic (seeded). Writes, in LaMAR Capture text format (COLMAP pixel convention for
intrinsics, world_from_cam poses):

    sample_data/scene/mesh.glb          textured mesh (single file, JPEG textures)
    sample_data/scene/sensors.txt       one PINHOLE camera, 320x240
    sample_data/scene/images.txt        timestamp, cam0, images/frame-XXXXXX.jpg
    sample_data/scene/trajectories.txt  the poses to check (some deliberately perturbed)
    sample_data/scene/perturbed.txt     which frames were perturbed, by how much
    sample_data/scene/images/*.jpg      the "captured" photos

The photos are rendered with pgt_check's renderer at the TRUE poses from a slightly different
scene (one object added, one moved), at 2x resolution then area-downsampled, and degraded
(exposure gain + gamma, a smooth illumination gradient with vignetting, colour cast, blur,
sensor noise, JPEG), so a plain render of mesh.glb never equals a photo. The trajectory file
holds the true poses except for the perturbed frames, whose pose is
``world_from_cam_true @ cam_true_from_cam_stored`` (rotation about an axis in the camera frame
and/or a translation in the camera frame, listed in perturbed.txt).

This file holds the camera, the trajectory and its perturbations, the photo degradation, the
capture files and the ``--check``; the room itself (textures, textured quads and boxes, the
"mesh" and "photo" variants) is built in ``sample_scene.py`` beside it.

Usage (pgt_check importable: pip install -e . or PYTHONPATH=.):
    python scripts/make_sample_data.py [--out sample_data/scene] [--check [--side-by-side DIR]]
``--check`` renders mesh.glb at every stored pose, matches render and photo with SIFT and
prints the homography corner error per frame (perturbed frames should stand out).
"""

from __future__ import annotations

import argparse
import logging
from pathlib import Path

import numpy as np
from sample_scene import build_scene

from pgt_check.geometry.transforms import (
    axis_angle_to_rotmat,
    invert_rigid,
    make_rigid,
    rotmat_to_quat,
)
from pgt_check.types import Camera

logger = logging.getLogger("make_sample_data")

SEED = 20240611
WIDTH, HEIGHT = 320, 240
FOCAL = 250.0
NUM_FRAMES = 24
# frame index -> (rotation deg, rotation axis (camera frame), translation (camera frame, m))
PERTURBATIONS: dict[int, tuple[float, tuple[float, float, float], tuple[float, float, float]]] = {
    3: (3.5, (0.0, 1.0, 0.0), (0.0, 0.0, 0.0)),
    7: (3.0, (1.0, 0.2, 0.0), (0.0, 0.0, 0.0)),
    11: (0.0, (0.0, 1.0, 0.0), (0.25, 0.0, 0.0)),
    15: (0.0, (0.0, 1.0, 0.0), (0.0, 0.2, -0.1)),
    18: (2.5, (0.3, 1.0, 0.5), (0.12, 0.05, 0.0)),
    21: (2.0, (1.0, 0.0, 0.3), (0.1, -0.1, 0.05)),
}


# -- trajectory and photos -----------------------------------------------------------------------


def look_at(eye: np.ndarray, target: np.ndarray) -> np.ndarray:
    """world_from_cam (OpenCV axes) for a camera at eye looking at target, world z up."""
    z = target - eye
    z /= np.linalg.norm(z)
    x = np.cross(z, [0.0, 0.0, 1.0])
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    return make_rigid(np.stack([x, y, z], axis=1), eye)


def true_trajectory() -> list[np.ndarray]:
    """A smooth walk around the room centre, looking outwards at the walls and boxes."""
    poses = []
    for i in range(NUM_FRAMES):
        s = i / (NUM_FRAMES - 1)
        ang = np.radians(-30 + 300 * s)
        eye = np.array([1.3 * np.cos(ang), 1.0 * np.sin(ang), 1.45 + 0.1 * np.sin(3 * ang)])
        look = ang + np.radians(25 * np.sin(2 * np.pi * s))
        target = eye + np.array([np.cos(look), np.sin(look), -0.25 + 0.1 * np.cos(2 * ang)])
        poses.append(look_at(eye, target))
    return poses


def perturb(world_from_cam: np.ndarray, rot_deg: float, axis, trans) -> np.ndarray:
    cam_true_from_cam_stored = make_rigid(
        axis_angle_to_rotmat(np.asarray(axis, float), rot_deg) if rot_deg else np.eye(3),
        np.asarray(trans, float),
    )
    return world_from_cam @ cam_true_from_cam_stored


def median_pixel_shift(render, camera: Camera, world_from_cam_a, world_from_cam_b) -> float:
    """Median image displacement of the surface seen in ``render`` (at pose a) when viewed
    from pose b: how far the stored pose moves the view."""
    v, u = np.nonzero(render.coverage)
    z = render.depth[v, u].astype(np.float64)
    rays = np.linalg.solve(camera.K, np.stack([u, v, np.ones_like(u)]).astype(float))
    pts_a = (rays * z).T
    b_from_a = invert_rigid(world_from_cam_b) @ world_from_cam_a
    pts_b = pts_a @ b_from_a[:3, :3].T + b_from_a[:3, 3]
    uvw = pts_b @ camera.K.T
    uv_b = uvw[:, :2] / uvw[:, 2:3]
    return float(np.median(np.linalg.norm(uv_b - np.stack([u, v], 1), axis=1)))


def degrade(rng: np.random.Generator, rgb: np.ndarray) -> np.ndarray:
    """Render (H, W, 3) float [0, 1] -> uint8 "photo": exposure, gradient, blur, noise."""
    import cv2

    h, w = rgb.shape[:2]
    gain = rng.uniform(0.8, 1.25)
    gamma = rng.uniform(0.8, 1.2)
    img = np.clip(rgb * gain, 0, 1) ** gamma
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    d = rng.normal(size=2)
    d /= np.linalg.norm(d)
    ramp = ((xx / w - 0.5) * d[0] + (yy / h - 0.5) * d[1]) * rng.uniform(0.3, 0.5)
    vignette = 1 - 0.35 * (((xx - w / 2) / w) ** 2 + ((yy - h / 2) / h) ** 2) * 2
    img = img * (1 + ramp)[:, :, None] * vignette[:, :, None]
    img = img * (1 + rng.normal(0, 0.04, 3))  # colour cast
    img = cv2.GaussianBlur(img.astype(np.float32), (0, 0), rng.uniform(0.5, 0.9))
    img = (
        img
        + rng.normal(0, 0.012, img.shape)
        + np.sqrt(np.clip(img, 0, 1)) * rng.normal(0, 0.02, img.shape)
    )
    return (np.clip(img, 0, 1) * 255 + 0.5).astype(np.uint8)


def camera() -> Camera:
    return Camera.pinhole(WIDTH, HEIGHT, FOCAL, FOCAL, (WIDTH - 1) / 2, (HEIGHT - 1) / 2)


def write_capture(out: Path, stored: list[np.ndarray], cam: Camera, perturbed_rows) -> None:
    fx, fy, cx, cy = cam.to_colmap_params()
    (out / "sensors.txt").write_text(
        "# sensor_id, name, sensor_type, [sensor_params]+\n"
        f"cam0, synthetic camera, camera, PINHOLE, {cam.width}, {cam.height}, "
        f"{fx:.6f}, {fy:.6f}, {cx:.6f}, {cy:.6f}\n"
    )
    lines = ["# timestamp, sensor_id, image_path"]
    lines += [f"{i}, cam0, images/frame-{i:06d}.jpg" for i in range(len(stored))]
    (out / "images.txt").write_text("\n".join(lines) + "\n")
    lines = ["# timestamp, device_id, qw, qx, qy, qz, tx, ty, tz"]
    for i, p in enumerate(stored):
        q = rotmat_to_quat(p[:3, :3])
        t = p[:3, 3]
        vals = ", ".join(f"{x:.9f}" for x in (*q, *t))
        lines.append(f"{i}, cam0, {vals}")
    (out / "trajectories.txt").write_text("\n".join(lines) + "\n")
    lines = [
        "# frame_id, rotation_deg, axis_x, axis_y, axis_z, tx, ty, tz, median_shift_px",
        "# stored world_from_cam = true world_from_cam @ [R(axis, rotation_deg) | t];"
        " axis and t in the camera frame (OpenCV axes), t in metres",
    ]
    lines += perturbed_rows
    (out / "perturbed.txt").write_text("\n".join(lines) + "\n")


def generate(out: Path) -> None:
    import cv2

    from pgt_check.render import load_mesh, make_renderer, mesh_from_trimesh

    rng = np.random.default_rng(SEED)
    out.mkdir(parents=True, exist_ok=True)
    (out / "images").mkdir(exist_ok=True)
    for old in (out / "images").glob("*.jpg"):
        old.unlink()
    mesh_scene = build_scene(np.random.default_rng(SEED + 1), "mesh")
    photo_scene = build_scene(np.random.default_rng(SEED + 1), "photo")
    mesh_scene.export(out / "mesh.glb")
    logger.info("mesh.glb: %.0f kB", (out / "mesh.glb").stat().st_size / 1e3)

    cam = camera()
    cam2 = cam.scaled(2.0)
    photo_renderer = make_renderer(mesh_from_trimesh(photo_scene))
    mesh_renderer = make_renderer(load_mesh(out / "mesh.glb"))
    truth = true_trajectory()
    stored, rows = [], []
    for i, world_from_cam in enumerate(truth):
        big = photo_renderer.render(cam2, world_from_cam)
        rgb = cv2.resize(big.rgb, (cam.width, cam.height), interpolation=cv2.INTER_AREA)
        photo = degrade(rng, rgb)
        cv2.imwrite(
            str(out / "images" / f"frame-{i:06d}.jpg"),
            photo[:, :, ::-1],
            [cv2.IMWRITE_JPEG_QUALITY, 88],
        )
        pose = world_from_cam
        if i in PERTURBATIONS:
            rot_deg, axis, trans = PERTURBATIONS[i]
            pose = perturb(world_from_cam, rot_deg, axis, trans)
            render = mesh_renderer.render(cam, world_from_cam)
            shift = median_pixel_shift(render, cam, world_from_cam, pose)
            a = np.asarray(axis, float) / np.linalg.norm(axis)
            vals = ", ".join(f"{x:.6f}" for x in (rot_deg, *a, *trans))
            rows.append(f"{i}/cam0, {vals}, {shift:.1f}")
            logger.info(
                "frame %d perturbed: %.1f deg, t=%s, median shift %.1f px", i, rot_deg, trans, shift
            )
        stored.append(pose)
    photo_renderer.close()
    mesh_renderer.close()
    write_capture(out, stored, cam, rows)


# -- check ---------------------------------------------------------------------------------------


def read_poses(path: Path) -> list[np.ndarray]:
    from pgt_check.geometry.transforms import quat_to_rotmat

    poses = []
    for line in path.read_text().splitlines():
        if line.startswith("#") or not line.strip():
            continue
        v = [s.strip() for s in line.split(",")]
        poses.append(make_rigid(quat_to_rotmat(np.array(v[2:6], float)), np.array(v[6:9], float)))
    return poses


def corner_error(render_rgb: np.ndarray, photo_bgr: np.ndarray) -> tuple[float, int, int]:
    """SIFT + ratio test + MAGSAC homography render -> photo; mean corner displacement (px)."""
    import cv2

    a = cv2.cvtColor((render_rgb * 255).astype(np.uint8), cv2.COLOR_RGB2GRAY)
    b = cv2.cvtColor(photo_bgr, cv2.COLOR_BGR2GRAY)
    sift = cv2.SIFT_create(2000)
    ka, da = sift.detectAndCompute(a, None)
    kb, db = sift.detectAndCompute(b, None)
    if da is None or db is None or len(ka) < 8 or len(kb) < 8:
        return float("inf"), 0, 0
    pairs = cv2.BFMatcher().knnMatch(da, db, k=2)
    good = [m for m, n in (p for p in pairs if len(p) == 2) if m.distance < 0.8 * n.distance]
    if len(good) < 8:
        return float("inf"), len(good), 0
    pa = np.float32([ka[m.queryIdx].pt for m in good])
    pb = np.float32([kb[m.trainIdx].pt for m in good])
    h, mask = cv2.findHomography(pa, pb, cv2.USAC_MAGSAC, 3.0)
    if h is None:
        return float("inf"), len(good), 0
    hh, ww = a.shape
    corners = np.float32([[0, 0], [ww - 1, 0], [ww - 1, hh - 1], [0, hh - 1]]).reshape(-1, 1, 2)
    warped = cv2.perspectiveTransform(corners, h)
    err = float(np.linalg.norm(warped - corners, axis=2).mean())
    return err, len(good), int(mask.sum())


def check(out: Path, side_by_side: Path | None) -> None:
    import cv2

    from pgt_check.render import load_mesh, make_renderer

    perturbed = {
        int(line.split("/")[0])
        for line in (out / "perturbed.txt").read_text().splitlines()
        if line and not line.startswith("#")
    }
    cam = camera()
    renderer = make_renderer(load_mesh(out / "mesh.glb"))
    good_err, bad_err = [], []
    for i, pose in enumerate(read_poses(out / "trajectories.txt")):
        r = renderer.render(cam, pose)
        photo = cv2.imread(str(out / "images" / f"frame-{i:06d}.jpg"))
        err, n, inl = corner_error(r.rgb, photo)
        (bad_err if i in perturbed else good_err).append(err)
        print(
            f"frame {i:2d} {'PERTURBED' if i in perturbed else 'ok       '} "
            f"coverage {r.coverage_fraction:.2f} matches {n:4d} inliers {inl:4d} "
            f"corner error {err:7.2f} px"
        )
        if side_by_side is not None and i in (0, min(perturbed)):
            both = np.hstack([(r.rgb[:, :, ::-1] * 255).astype(np.uint8), photo])
            cv2.imwrite(str(side_by_side / f"sample_{i:02d}.png"), both)
    renderer.close()
    print(f"unperturbed: median {np.median(good_err):.2f} px, max {np.max(good_err):.2f} px")
    print(f"perturbed:   median {np.median(bad_err):.2f} px, min {np.min(bad_err):.2f} px")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument(
        "--out", type=Path, default=Path(__file__).resolve().parents[1] / "sample_data" / "scene"
    )
    parser.add_argument("--check", action="store_true", help="only run the SIFT check")
    parser.add_argument(
        "--side-by-side",
        type=Path,
        default=None,
        help="with --check: folder for render|photo PNGs of two frames",
    )
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    if not args.check:
        generate(args.out)
    else:
        check(args.out, args.side_by_side)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
