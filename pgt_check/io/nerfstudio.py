"""nerfstudio / instant-ngp ``transforms.json``.

What the file stores: ``frames[].transform_matrix`` is **cam-to-world in OpenGL camera axes**
(x right, y up, z backwards); the reader converts to OpenCV axes with
``world_from_cam = M @ diag(1, -1, -1, 1)``. Intrinsics (``fl_x, fl_y, cx, cy, w, h``, optional
``k1, k2, k3, p1, p2``; or instant-ngp's ``camera_angle_x``) are global or per frame; nerfstudio's
principal point puts the top-left pixel centre at (0.5, 0.5), so 0.5 is subtracted from cx, cy.
``file_path`` is relative to the json's folder. An ``applied_transform`` (nerfstudio's record of
the world-axis change it made when converting from COLMAP) is not undone; it is kept in the
trajectory metadata.

Poses exported from a trained nerfstudio model live in its dataparser frame: nerfstudio stored
``M' = T @ M`` with the translation then multiplied by ``scale`` (``dataparser_transforms.json``:
``transform`` 3x4, ``scale``). ``read_nerfstudio(..., dataparser_transforms=PATH)`` undoes that:
``M = T^-1 @ [R' | t' / scale]``.
"""

from __future__ import annotations

import json
import logging
import math
from pathlib import Path
from typing import Any

import numpy as np

from pgt_check.common.files import MAX_INPUT_TEXT_BYTES, load_json_limited
from pgt_check.errors import FormatError, InputError
from pgt_check.io._text import UniqueKeys, check_frame_id
from pgt_check.io.camera import COLMAP_PIXEL_OFFSET
from pgt_check.io.images import image_size
from pgt_check.types import Camera, Frame, Trajectory

logger = logging.getLogger(__name__)

#: OpenGL camera axes (x right, y up, z back) -> OpenCV (x right, y down, z forward)
GL_FROM_CV = np.diag([1.0, -1.0, -1.0, 1.0])

INTRINSIC_KEYS = ("fl_x", "fl_y", "cx", "cy", "w", "h", "camera_angle_x", "camera_angle_y")
DISTORTION_KEYS = ("k1", "k2", "k3", "k4", "p1", "p2")
SUPPORTED_MODELS = ("OPENCV", "PINHOLE", "SIMPLE_PINHOLE")


def load_json(path: Path) -> Any:
    """A JSON file (UTF-8, a BOM allowed) of at most ``MAX_INPUT_TEXT_BYTES``; InputError /
    FormatError for a missing, special or oversized file, bad JSON or too deep nesting."""
    return load_json_limited(path, MAX_INPUT_TEXT_BYTES)


def _number(path: Path, where: str, key: str, value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise FormatError(
            path, None, f"{where}: expected a finite number for {key!r}; got {value!r}"
        )
    return float(value)


def _field_of_view(path: Path, where: str, key: str, num: dict[str, float]) -> float:
    """A field of view in radians, strictly between 0 and pi (a focal length exists)."""
    angle = num[key]
    if not 0.0 < angle < math.pi:
        raise FormatError(
            path, None, f"{where}: expected {key!r} in (0, pi) radians; got {angle!r}"
        )
    return angle


def _resolve_image(directory: Path, file_path: str) -> Path:
    """``directory / file_path``; instant-ngp's Blender files omit the extension: try .png."""
    file = directory / file_path
    if not file.suffix and not file.exists() and file.with_suffix(".png").exists():
        return file.with_suffix(".png")
    return file


def _camera(path: Path, where: str, values: dict[str, Any], image: Path) -> Camera:
    """A Camera from merged global + per-frame keys."""
    model = values.get("camera_model", "OPENCV")
    if model not in SUPPORTED_MODELS:
        raise FormatError(
            path,
            None,
            f"{where}: expected camera_model in {', '.join(SUPPORTED_MODELS)}; got {model!r}",
        )
    num = {
        k: _number(path, where, k, values[k])
        for k in (*INTRINSIC_KEYS, *DISTORTION_KEYS)
        if k in values
    }
    width, height = _camera_size(path, where, num, image)
    fx, fy = _focal_lengths(path, where, num, width, height)
    cx = num.get("cx", width / 2.0) - COLMAP_PIXEL_OFFSET
    cy = num.get("cy", height / 2.0) - COLMAP_PIXEL_OFFSET
    dist = {k: num.get(k, 0.0) for k in DISTORTION_KEYS}
    if dist["k4"]:
        raise FormatError(
            path, None, f"{where}: expected no k4 for a perspective camera; got {dist['k4']}"
        )
    try:
        return _camera_from_intrinsics(width, height, fx, fy, cx, cy, dist)
    except ValueError as err:
        raise FormatError(path, None, f"{where}: expected a valid camera; got {err}") from None


def _camera_size(path: Path, where: str, num: dict[str, float], image: Path) -> tuple[float, float]:
    """(width, height): ``w`` and ``h`` if both are given, else the image's size; checked to be
    positive integers."""
    if "w" in num and "h" in num:
        width, height = num["w"], num["h"]
    else:
        try:
            width, height = image_size(image)
        except InputError as err:
            raise FormatError(
                path,
                None,
                f"{where}: expected 'w' and 'h' or a readable image to size the camera; got {err}",
            ) from None
    if width != int(width) or height != int(height) or width <= 0 or height <= 0:
        raise FormatError(
            path, None, f"{where}: expected positive integer 'w' and 'h'; got {width}x{height}"
        )
    return width, height


def _focal_lengths(
    path: Path, where: str, num: dict[str, float], width: float, height: float
) -> tuple[float, float]:
    """(fx, fy) in pixels from ``fl_x`` / ``fl_y`` or the fields of view; fy defaults to fx."""
    if "fl_x" in num:
        fx = num["fl_x"]
    elif "camera_angle_x" in num:
        fx = 0.5 * width / math.tan(0.5 * _field_of_view(path, where, "camera_angle_x", num))
    else:
        raise FormatError(path, None, f"{where}: expected 'fl_x' or 'camera_angle_x'; got neither")
    if "fl_y" in num:
        fy = num["fl_y"]
    elif "camera_angle_y" in num:
        fy = 0.5 * height / math.tan(0.5 * _field_of_view(path, where, "camera_angle_y", num))
    else:
        fy = fx
    return fx, fy


def _camera_from_intrinsics(
    width: float,
    height: float,
    fx: float,
    fy: float,
    cx: float,
    cy: float,
    dist: dict[str, float],
) -> Camera:
    """The simplest Camera that holds the distortion: FULL_OPENCV with k3, OPENCV with k1, k2,
    p1 or p2, else a pinhole; ValueError for an invalid camera."""
    params: tuple[float, ...]
    if dist["k3"]:
        params = (
            fx,
            fy,
            cx,
            cy,
            dist["k1"],
            dist["k2"],
            dist["p1"],
            dist["p2"],
            dist["k3"],
            0.0,
            0.0,
            0.0,
        )
        return Camera("FULL_OPENCV", int(width), int(height), params)
    if any(dist[k] for k in ("k1", "k2", "p1", "p2")):
        params = (fx, fy, cx, cy, dist["k1"], dist["k2"], dist["p1"], dist["p2"])
        return Camera("OPENCV", int(width), int(height), params)
    return Camera.pinhole(int(width), int(height), fx, fy, cx, cy)


def read_dataparser_transforms(path: str | Path) -> tuple[np.ndarray, float]:
    """(4x4 rigid ``transform``, ``scale``) of a nerfstudio ``dataparser_transforms.json``."""
    path = Path(path)
    data = load_json(path)
    if not isinstance(data, dict) or "transform" not in data or "scale" not in data:
        raise FormatError(path, None, "expected an object with 'transform' (3x4) and 'scale'")
    try:
        t = np.asarray(data["transform"], dtype=np.float64)
    except (TypeError, ValueError):
        t = np.zeros(0)
    if t.shape == (3, 4):
        t = np.vstack([t, [0.0, 0.0, 0.0, 1.0]])
    if t.shape != (4, 4) or not np.all(np.isfinite(t)):
        raise FormatError(
            path, None, f"expected a finite 3x4 'transform'; got {data['transform']!r:.80}"
        )
    r = t[:3, :3]
    if not np.allclose(r @ r.T, np.eye(3), atol=1e-6) or np.linalg.det(r) < 0:
        raise FormatError(path, None, "expected 'transform' to be a rotation and a translation")
    scale = _number(path, "dataparser", "scale", data["scale"])
    if scale <= 0:
        raise FormatError(path, None, f"expected a positive 'scale'; got {scale}")
    return t, scale


def undo_dataparser_transform(
    matrix: np.ndarray, transform: np.ndarray, scale: float
) -> np.ndarray:
    """(4, 4) pose in nerfstudio's dataparser frame -> the original frame (see module doc)."""
    unscaled = np.array(matrix, dtype=np.float64)
    unscaled[:3, 3] /= scale
    return np.linalg.inv(transform) @ unscaled


def read_nerfstudio(
    path: str | Path,
    *,
    images: str | Path | None = None,
    dataparser_transforms: str | Path | None = None,
) -> Trajectory:
    """Read a ``transforms.json`` (or a folder holding one) into world_from_cam frames.

    frame_id and image_path are ``file_path`` as written; files are resolved against ``images``
    (default: the json's folder). Frames keep the file's order. ``dataparser_transforms``: a
    nerfstudio ``dataparser_transforms.json`` whose transform and scale are undone (poses
    exported in a trained model's frame back to the data's frame).
    """
    path = Path(path)
    undo = (
        read_dataparser_transforms(dataparser_transforms)
        if dataparser_transforms is not None
        else None
    )
    if path.is_dir():
        path = path / "transforms.json"
    data = load_json(path)
    if not isinstance(data, dict) or not isinstance(data.get("frames"), list):
        raise FormatError(path, None, "expected a JSON object with a 'frames' list; got none")
    if not data["frames"]:
        raise FormatError(path, None, "expected at least one entry in 'frames'; got an empty list")
    root = Path(images) if images is not None else path.parent
    shared = {k: v for k, v in data.items() if k != "frames"}
    seen = UniqueKeys(path, "unique 'file_path'")
    frames = [
        _frame(path, f"frames[{i}]", entry, shared, root, undo, seen)
        for i, entry in enumerate(data["frames"])
    ]
    metadata = {"images_dir": str(root)}
    if dataparser_transforms is not None:
        metadata["dataparser_transforms"] = str(dataparser_transforms)
    if "applied_transform" in data:
        metadata["applied_transform"] = json.dumps(data["applied_transform"])
        logger.info("%s: has an applied_transform; poses are kept in the file's world frame", path)
    logger.info("read %d frames from %s", len(frames), path)
    return Trajectory(tuple(frames), source=str(path), format="nerfstudio", metadata=metadata)


def _frame(
    path: Path,
    where: str,
    entry: Any,
    shared: dict[str, Any],
    root: Path,
    undo: tuple[np.ndarray, float] | None,
    seen: UniqueKeys,
) -> Frame:
    """The Frame of one ``frames[]`` entry (world_from_cam in OpenCV axes), checked."""
    if not isinstance(entry, dict):
        raise FormatError(path, None, f"{where}: expected an object; got {type(entry).__name__}")
    file_path = entry.get("file_path")
    if not isinstance(file_path, str) or not file_path:
        raise FormatError(path, None, f"{where}: expected a 'file_path' string; got {file_path!r}")
    check_frame_id(path, None, file_path, where=where, what="'file_path'")
    image = _resolve_image(root, file_path)
    camera = _camera(path, where, {**shared, **entry}, image)
    matrix = _transform_matrix(path, where, entry)
    if undo is not None:
        matrix = undo_dataparser_transform(matrix, *undo)
    seen.add(file_path, repr(file_path), None, where)
    try:
        return Frame(file_path, camera, matrix @ GL_FROM_CV, file_path, image)
    except ValueError as err:
        raise FormatError(
            path, None, f"{where}: expected a rigid cam-to-world 'transform_matrix'; got {err}"
        ) from None


def _transform_matrix(path: Path, where: str, entry: dict[str, Any]) -> np.ndarray:
    """An entry's ``transform_matrix`` as a (4, 4) float array (a 3x4 gets the row 0 0 0 1)."""
    try:
        matrix = np.asarray(entry.get("transform_matrix"), dtype=np.float64)
    except (TypeError, ValueError):
        matrix = np.zeros(0)
    if matrix.shape == (3, 4):
        matrix = np.vstack([matrix, [0.0, 0.0, 0.0, 1.0]])
    if matrix.shape != (4, 4):
        raise FormatError(
            path,
            None,
            f"{where}: expected a 4x4 'transform_matrix'; got {entry.get('transform_matrix')!r:.80}",
        )
    return matrix
