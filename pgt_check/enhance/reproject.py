"""Classical, geometric enhancement: colour the render with a reference photo through the mesh.

For every render pixel with depth, the 3D surface point seen at the frame's pose is projected
into the reference camera; where the reference also sees that surface (its own render depth
agrees within ``depth_tolerance``), the pixel takes the reference photo's colour. Elsewhere the
render's own colour stays. The geometry of the result is the render's (it is a function of the
frame's pose only), so a wrong pose still shows as a displaced image; the appearance is the
reference photo's, which closes the domain gap of colourless or blurry meshes.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from pgt_check.enhance.base import EnhancedImage, Evidence, ReferenceView, View
from pgt_check.geometry.transforms import invert_rigid
from pgt_check.render.base import Renderer
from pgt_check.types import Camera, check_shape


def reproject_reference(
    render_rgb: np.ndarray,
    render_depth: np.ndarray,
    camera: Camera,
    world_from_cam: np.ndarray,
    reference_photo: np.ndarray,
    reference_depth: np.ndarray,
    reference_camera: Camera,
    world_from_reference: np.ndarray,
    depth_tolerance: float = 0.03,
) -> tuple[np.ndarray, np.ndarray]:
    """Warp ``reference_photo`` into the render's view using the render depth.

    render_rgb: (h, w, 3) float32; render_depth: (h, w) float32 metric z (0 = no hit), both for
    ``camera`` (pinhole, OpenCV pixels) at ``world_from_cam``. reference_photo: (hr, wr, 3)
    float32 and reference_depth (hr, wr) for ``reference_camera`` at ``world_from_reference``.
    Returns (image (h, w, 3) float32, filled (h, w) bool).
    """
    import cv2

    h, w = render_depth.shape
    check_shape("render_rgb", render_rgb, (h, w, 3))
    hr, wr = reference_depth.shape
    check_shape("reference_photo", reference_photo, (hr, wr, 3))
    if (camera.width, camera.height) != (w, h):
        raise ValueError(f"camera is {camera.width}x{camera.height}, render is {w}x{h}")
    if (reference_camera.width, reference_camera.height) != (wr, hr):
        raise ValueError("reference camera size does not match the reference images")
    ref_from_cam = invert_rigid(world_from_reference) @ np.asarray(world_from_cam, np.float64)
    fx, fy = camera.focal
    cx, cy = camera.principal_point
    v, u = np.nonzero(render_depth > 0)
    z = render_depth[v, u].astype(np.float64)
    pts = np.stack([(u - cx) / fx * z, (v - cy) / fy * z, z], axis=1)
    pr = pts @ ref_from_cam[:3, :3].T + ref_from_cam[:3, 3]
    rfx, rfy = reference_camera.focal
    rcx, rcy = reference_camera.principal_point
    zr = pr[:, 2]
    in_front = zr > 1e-9
    with np.errstate(divide="ignore", invalid="ignore"):
        ur = np.where(in_front, rfx * pr[:, 0] / zr + rcx, -1e9)
        vr = np.where(in_front, rfy * pr[:, 1] / zr + rcy, -1e9)
    inside = in_front & (ur >= 0) & (ur <= wr - 1) & (vr >= 0) & (vr <= hr - 1)
    ui = np.clip(np.round(ur).astype(np.int64), 0, wr - 1)
    vi = np.clip(np.round(vr).astype(np.int64), 0, hr - 1)
    dref = reference_depth[vi, ui].astype(np.float64)
    visible = inside & (dref > 0) & (np.abs(dref - zr) <= depth_tolerance * zr)
    map_x = np.full((h, w), -1.0, np.float32)
    map_y = np.full((h, w), -1.0, np.float32)
    map_x[v[visible], u[visible]] = ur[visible]
    map_y[v[visible], u[visible]] = vr[visible]
    sampled = cv2.remap(
        reference_photo.astype(np.float32), map_x, map_y, cv2.INTER_LINEAR,
        borderMode=cv2.BORDER_CONSTANT, borderValue=0,
    )
    filled = np.zeros((h, w), bool)
    filled[v[visible], u[visible]] = True
    out = np.where(filled[..., None], sampled, render_rgb).astype(np.float32)
    return np.clip(out, 0.0, 1.0), filled


class ReprojectEnhancer:
    """The reprojection method behind the enhancer interface (relative evidence: the reference
    photo is placed by the reference's own pose)."""

    name = "reproject"
    evidence = Evidence.RELATIVE
    detail_short_side = None  # the reference photo's own detail, at the render's size

    @classmethod
    def from_config(cls, config: Any) -> ReprojectEnhancer:
        return cls()

    def enhance(self, view: View, reference: ReferenceView, renderer: Renderer) -> EnhancedImage:
        ref_render = renderer.render(reference.camera, reference.world_from_cam)
        image, filled = reproject_reference(
            view.render.rgb, view.render.depth, view.camera, view.world_from_cam,
            reference.photo, ref_render.depth, reference.camera, reference.world_from_cam,
        )
        return EnhancedImage(image, filled)
