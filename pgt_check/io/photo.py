"""Photo preparation at the package edge: the photo and its camera brought to one pinhole model
and to the working (matching) resolution."""

from __future__ import annotations

import numpy as np

from pgt_check.errors import ImageSizeMismatchError
from pgt_check.types import Camera

#: the largest factor between camera size and photo size accepted as a resized capture
MAX_RESIZE_FACTOR = 8.0


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
    Distorted camera models (fisheye included) are undistorted to their pinhole part. Raises
    ImageSizeMismatchError for an incompatible size: another aspect ratio, or a scale outside
    1/MAX_RESIZE_FACTOR .. MAX_RESIZE_FACTOR (a camera 10,000x larger than its photo is a wrong
    camera, not a resized capture).
    """
    from pgt_check.io.camera import undistort_to_pinhole

    h, w = image.shape[:2]
    if (w, h) != (camera.width, camera.height):
        if abs(w / h - camera.width / camera.height) > 0.01 * camera.width / camera.height:
            raise ImageSizeMismatchError(
                f"image size {w}x{h} does not match camera {camera.width}x{camera.height}"
            )
        factor = camera.width / w
        if not 1.0 / MAX_RESIZE_FACTOR <= factor <= MAX_RESIZE_FACTOR:
            raise ImageSizeMismatchError(
                f"image size {w}x{h} is {factor:.4g}x smaller than camera "
                f"{camera.width}x{camera.height} (at most {MAX_RESIZE_FACTOR:g}x is taken as a "
                "resized capture)"
            )
        if not camera.is_distorted:
            camera = camera.scaled(w / camera.width, h / camera.height)
    return undistort_to_pinhole(image, camera)
