"""Photo preparation at the package edge: the photo and its camera brought to one pinhole model
and to the working (matching) resolution."""

from __future__ import annotations

import numpy as np

from pgt_check.errors import InputError
from pgt_check.types import Camera


def working_scale(width: int, height: int, resize_max: int | None) -> tuple[int, int]:
    """Size (w, h) of the working images: the longest side capped at ``resize_max``."""
    if resize_max is None or max(width, height) <= resize_max:
        return width, height
    s = resize_max / max(width, height)
    return max(1, round(width * s)), max(1, round(height * s))


def prepare_photo(image: np.ndarray, camera: Camera) -> tuple[np.ndarray, Camera]:
    """Bring a photo to the camera's pinhole model and size.

    image: (H, W, 3) float32 RGB. A photo whose size differs from the camera's but has the same
    aspect ratio (within 1 %) is treated as a resized capture and the camera is scaled to it.
    Distorted camera models (fisheye included) are undistorted to their pinhole part. Raises InputError for an
    incompatible size.
    """
    from pgt_check.io.camera import undistort_to_pinhole

    h, w = image.shape[:2]
    if (w, h) != (camera.width, camera.height):
        if abs(w / h - camera.width / camera.height) > 0.01 * camera.width / camera.height:
            raise InputError(
                f"image size {w}x{h} does not match camera {camera.width}x{camera.height}"
            )
        if not camera.is_distorted:
            camera = camera.scaled(w / camera.width, h / camera.height)
    return undistort_to_pinhole(image, camera)
