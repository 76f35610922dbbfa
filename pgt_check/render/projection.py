"""Pure functions shared by render backends: OpenGL projection from OpenCV intrinsics and
near/far planes from the mesh bounds."""

from __future__ import annotations

import numpy as np

from pgt_check.geometry.transforms import invert_rigid
from pgt_check.types import Camera, check_shape


def opengl_projection(camera: Camera, znear: float, zfar: float) -> np.ndarray:
    """(4, 4) float64 projection acting directly on OpenCV camera coordinates.

    x right, y down, z forward; pixel (u, v) in OpenCV convention (top-left pixel centre at
    (0, 0)) maps to NDC (2(u+0.5)/w - 1, 2(v+0.5)/h - 1), so row 0 of glReadPixels (NDC y = -1)
    is the image top: the read-back needs no flip. Depth: z = znear -> -1, z = zfar -> +1.
    """
    if not 0.0 < znear < zfar:
        raise ValueError(f"need 0 < znear < zfar, got {znear}, {zfar}")
    fx, fy = camera.focal
    cx, cy = camera.principal_point
    w, h = camera.width, camera.height
    p = np.zeros((4, 4))
    p[0, 0] = 2.0 * fx / w
    p[0, 2] = 2.0 * (cx + 0.5) / w - 1.0
    p[1, 1] = 2.0 * fy / h
    p[1, 2] = 2.0 * (cy + 0.5) / h - 1.0
    p[2, 2] = (zfar + znear) / (zfar - znear)
    p[2, 3] = -2.0 * zfar * znear / (zfar - znear)
    p[3, 2] = 1.0
    return p


def _max_ray_cos(camera: Camera) -> float:
    """Smallest cos(angle to the optical axis) over the image corners' rays."""
    fx, fy = camera.focal
    cx, cy = camera.principal_point
    xs = (np.array([-0.5, camera.width - 0.5]) - cx) / fx
    ys = (np.array([-0.5, camera.height - 0.5]) - cy) / fy
    r2 = np.max(xs**2)[None] + np.max(ys**2)  # type: ignore[index]  # a numpy scalar indexes
    return float(1.0 / np.sqrt(1.0 + r2[0]))


def near_far_from_bounds(
    cam_from_world: np.ndarray,
    bounds: np.ndarray,
    camera: Camera,
    near_ratio: float = 1e-4,
) -> tuple[float, float] | None:
    """Clip planes (znear, zfar) that enclose ``bounds`` seen from the camera, or None if the
    whole box is behind the camera.

    cam_from_world: (4, 4) float64 (in the same, possibly recentred, frame as bounds).
    bounds: (2, 3) float64 axis-aligned box.
    zfar is 1 % beyond the farthest box corner; znear is the distance to the box scaled by the
    widest ray's cosine (so nothing in view is clipped) but at least ``near_ratio * zfar``
    (keeps 24-bit depth-test resolution near zfar * 6e-4 / near_ratio * 1e-4; metric depth is
    read from a float32 attachment and does not depend on it).
    """
    bounds = np.asarray(bounds, dtype=np.float64)
    check_shape("bounds", bounds, (2, 3))
    corners = np.array(
        [[bounds[i, 0], bounds[j, 1], bounds[k, 2]] for i in (0, 1) for j in (0, 1) for k in (0, 1)]
    )
    z = corners @ cam_from_world[2, :3] + cam_from_world[2, 3]
    zmax = float(z.max())
    if zmax <= 0.0:
        return None
    zfar = zmax * 1.01
    centre = -cam_from_world[:3, :3].T @ cam_from_world[:3, 3]
    closest = np.clip(centre, bounds[0], bounds[1])
    dist = float(np.linalg.norm(centre - closest))
    znear = max(0.99 * dist * _max_ray_cos(camera), near_ratio * zfar)
    if znear >= zfar:
        znear = zfar * 0.5
    return znear, zfar


def centred_view(
    camera: Camera,
    world_from_cam: np.ndarray,
    offset: np.ndarray,
    bounds_centred: np.ndarray,
    near_ratio: float,
) -> tuple[Camera, np.ndarray, tuple[float, float] | None]:
    """What every backend does before drawing one view.

    Checks ``world_from_cam`` (4x4, finite), renders a distorted camera as its pinhole model
    (the IO layer undistorts photos to the same model), recentres the pose by the mesh's
    float64 ``offset`` (the camera centre moves with the vertices) and finds the clip planes.
    Returns (pinhole camera, centred_from_cam (4, 4), (znear, zfar) or None when nothing of
    the mesh can be in front of the camera).
    """
    import logging

    world_from_cam = np.asarray(world_from_cam, dtype=np.float64)
    check_shape("world_from_cam", world_from_cam, (4, 4))
    if not np.all(np.isfinite(world_from_cam)):
        raise ValueError("world_from_cam is not finite")
    if camera.is_distorted:
        logging.getLogger(__name__).debug(
            "rendering distorted %s camera as its pinhole model", camera.model
        )
    camera = camera.as_pinhole()
    centred_from_cam = world_from_cam.copy()
    centred_from_cam[:3, 3] -= offset
    planes = near_far_from_bounds(invert_rigid(centred_from_cam), bounds_centred, camera,
                                  near_ratio)
    return camera, centred_from_cam, planes
