"""Cameras at the reader edge: the COLMAP pixel shift, camera specs, pycolmap, undistortion.

COLMAP, LaMAR and nerfstudio put the centre of the top-left pixel at (0.5, 0.5); the package
(OpenCV) puts it at (0, 0). ``colmap_to_opencv_params`` / ``opencv_to_colmap_params`` are the one
place where that shift is applied.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from pgt_check.errors import FormatError, InputError
from pgt_check.types import (
    CAMERA_MODELS,
    COLMAP_PIXEL_OFFSET,
    Camera,
    colmap_to_opencv_params,
    opencv_to_colmap_params,
)

logger = logging.getLogger(__name__)


def camera_from_colmap(
    path: Path | str,
    line: int | None,
    model: str,
    width: float,
    height: float,
    params: Sequence[float],
) -> Camera:
    """A Camera from COLMAP-convention values read from ``path`` (FormatError naming the line)."""
    if model not in CAMERA_MODELS:
        raise FormatError(
            path, line, f"expected a camera model in {', '.join(CAMERA_MODELS)}; got {model!r}"
        )
    names = CAMERA_MODELS[model]
    if len(params) != len(names):
        raise FormatError(
            path,
            line,
            f"expected {len(names)} parameters for {model} ({', '.join(names)}); got {len(params)}",
        )
    if width != int(width) or height != int(height):
        raise FormatError(path, line, f"expected integer image size; got {width}x{height}")
    try:
        return Camera(model, int(width), int(height), colmap_to_opencv_params(model, params))
    except ValueError as err:
        raise FormatError(path, line, f"expected a valid camera; got {err}") from None


def parse_camera_spec(spec: str) -> Camera:
    """Parse ``"MODEL,width,height,p1,p2,..."`` (COLMAP parameter order and pixel convention).

    The principal point in the string follows COLMAP (centre of the top-left pixel at
    (0.5, 0.5)), as in a COLMAP ``cameras.txt`` line; the returned Camera is in OpenCV
    convention (0.5 subtracted from cx, cy). Commas and/or whitespace separate the fields.
    Raises InputError with the expected layout on any problem.
    """
    fields = [f for f in spec.replace(",", " ").split() if f]
    if not fields:
        raise InputError("camera spec is empty; expected MODEL,width,height,params...")
    model = fields[0].upper()
    if model not in CAMERA_MODELS:
        raise InputError(
            f"camera spec {spec!r}: expected a model in {', '.join(CAMERA_MODELS)}; got {fields[0]!r}"
        )
    names = CAMERA_MODELS[model]
    layout = f"{model},width,height,{','.join(names)}"
    if len(fields) != 3 + len(names):
        raise InputError(
            f"camera spec {spec!r}: expected {3 + len(names)} fields ({layout}); got {len(fields)}"
        )
    try:
        width, height = int(fields[1]), int(fields[2])
        params = [float(p) for p in fields[3:]]
    except ValueError:
        raise InputError(
            f"camera spec {spec!r}: expected integer width, height and numeric parameters ({layout})"
        ) from None
    try:
        return Camera(model, width, height, colmap_to_opencv_params(model, params))
    except ValueError as err:
        raise InputError(f"camera spec {spec!r}: {err}") from None


def _pycolmap() -> Any:
    try:
        import pycolmap
    except ImportError as err:
        raise InputError("this camera model needs pycolmap: pip install pycolmap") from err
    return pycolmap


def to_pycolmap(camera: Camera) -> Any:
    """The ``pycolmap.Camera`` of a Camera (COLMAP pixel convention: cx, cy + 0.5)."""
    pycolmap = _pycolmap()
    if camera.model not in pycolmap.CameraModelId.__members__:
        raise InputError(
            f"camera model {camera.model} is not known to pycolmap {pycolmap.__version__}; "
            "upgrade pycolmap"
        )
    return pycolmap.Camera(
        model=camera.model,
        width=camera.width,
        height=camera.height,
        params=list(opencv_to_colmap_params(camera.model, camera.params)),
    )


def distort_points(camera: Camera, points: np.ndarray) -> np.ndarray:
    """(N, 2) pixels of the pinhole ``camera.as_pinhole()`` -> (N, 2) pixels of ``camera``.

    Both in OpenCV convention; rays are cast through the pinhole and projected with the full
    model by pycolmap. Used to build undistortion maps (and by tests to make distorted data).
    """
    points = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    fx, fy = camera.focal
    cx, cy = camera.principal_point
    rays = np.column_stack(
        [(points[:, 0] - cx) / fx, (points[:, 1] - cy) / fy, np.ones(len(points))]
    )
    out = np.asarray(to_pycolmap(camera).img_from_cam(rays), dtype=np.float64)
    return out.reshape(-1, 2) - COLMAP_PIXEL_OFFSET


def undistort_to_pinhole(
    image: np.ndarray, camera: Camera, *, pinhole: Camera | None = None
) -> tuple[np.ndarray, Camera]:
    """Warp an (H, W, C) image of ``camera`` (any model) to a pinhole camera.

    ``pinhole``: the target PINHOLE/SIMPLE_PINHOLE camera; default ``camera.as_pinhole()`` (same
    size, focal length and principal point, distortion dropped: what the renderer draws). A camera
    without distortion returns the image and camera unchanged (the same objects). Every target
    pixel looks up its ray in the source image through the model (pycolmap ``img_from_cam``),
    bilinear, black outside. Returns (image, pinhole camera); the pose is unchanged.
    """
    import cv2

    image = np.asarray(image)
    if image.ndim not in (2, 3) or image.shape[:2] != (camera.height, camera.width):
        raise ValueError(
            f"image: expected shape ({camera.height}, {camera.width}[, C]) to match the camera, "
            f"got {image.shape}"
        )
    if not camera.is_distorted and pinhole is None:
        return image, camera
    target = camera.as_pinhole() if pinhole is None else pinhole
    if target.is_distorted:
        raise ValueError(f"pinhole: expected a camera without distortion, got {target.model}")
    xs, ys = np.meshgrid(
        np.arange(target.width, dtype=np.float64), np.arange(target.height, dtype=np.float64)
    )
    # rays of the target pinhole, expressed as pixels of camera.as_pinhole() for distort_points
    fx, fy = camera.focal
    cx, cy = camera.principal_point
    tfx, tfy = target.focal
    tcx, tcy = target.principal_point
    px = (xs.ravel() - tcx) / tfx * fx + cx
    py = (ys.ravel() - tcy) / tfy * fy + cy
    src = distort_points(camera, np.column_stack([px, py]))
    map_x = src[:, 0].reshape(target.height, target.width).astype(np.float32)
    map_y = src[:, 1].reshape(target.height, target.width).astype(np.float32)
    warped = cv2.remap(
        image, map_x, map_y, interpolation=cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT
    )
    return warped, target
