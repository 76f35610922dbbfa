"""COLMAP sparse models (text or binary), read with pycolmap.

What the files store: ``images.{txt,bin}`` hold **cam_from_world** (``p_cam = R(q) p_world + t``),
OpenCV camera axes; ``cameras.{txt,bin}`` hold COLMAP camera models in the COLMAP pixel convention
(top-left pixel centre at (0.5, 0.5)). The reader inverts the poses and subtracts 0.5 from cx, cy.
"""

from __future__ import annotations

import logging
import os
from pathlib import Path
from typing import Any

import numpy as np

from pgt_check.common.files import regular_file_size
from pgt_check.errors import FormatError, InputError
from pgt_check.geometry.transforms import invert_rigid
from pgt_check.io._text import QuaternionCounter, check_frame_id
from pgt_check.io.camera import camera_from_colmap
from pgt_check.types import Camera, Frame, Trajectory

logger = logging.getLogger(__name__)

MODEL_FILES = ("cameras", "images", "points3D", "rigs", "frames")


def _has_cameras(directory: Path) -> bool:
    return any((directory / f"cameras.{ext}").is_file() for ext in ("txt", "bin"))


def colmap_model_dir(path: str | Path) -> Path | None:
    """The model directory for a model directory, one of its files or a COLMAP project root.

    A project root (a folder with ``sparse/0/`` or ``sparse/`` holding cameras.txt/.bin) is
    descended into; with several numbered models ``sparse/0`` is taken (logged at INFO).
    """
    path = Path(path)
    directory = path if path.is_dir() else path.parent
    if path.is_file() and path.stem not in MODEL_FILES:
        return None
    if _has_cameras(directory):
        return directory
    if path.is_dir():
        sparse = path / "sparse"
        numbered = sorted(
            (d for d in sparse.glob("[0-9]*") if d.name.isdigit() and _has_cameras(d)),
            key=lambda d: int(d.name),
        )
        if numbered:
            if len(numbered) > 1:
                logger.info(
                    "%s: %d models under sparse/; reading %s", path, len(numbered), numbered[0]
                )
            return numbered[0]
        if _has_cameras(sparse):
            return sparse
    return None


def default_images_dir(model_dir: Path) -> Path:
    """``<model>/../images`` (or ``<model>/../../images`` for ``sparse/0``), else the model dir."""
    for candidate in (model_dir.parent / "images", model_dir.parent.parent / "images"):
        if candidate.is_dir():
            return candidate
    return model_dir


def _cam_from_world(image: object, quats: QuaternionCounter | None = None) -> np.ndarray:
    """(4, 4) cam_from_world of a pycolmap Image (a method in pycolmap >= 3.12, a property before).

    With ``quats``, the stored quaternion is checked as the TUM / LaMAR readers check theirs
    (pycolmap keeps it as written: a zero quaternion would read as the identity): FormatError
    beyond the norm tolerance, normalised with a counted warning otherwise."""
    pose = image.cam_from_world  # type: ignore[attr-defined]
    if callable(pose):
        pose = pose()
    matrix = np.eye(4)
    matrix[:3, :] = np.asarray(pose.matrix(), dtype=np.float64)
    quat = getattr(getattr(pose, "rotation", None), "quat", None)
    if quats is not None and quat is not None:
        x, y, z, w = (float(v) for v in np.asarray(quat, dtype=np.float64))  # Eigen: xyzw
        try:
            matrix[:3, :3] = quats.rotation(None, (w, x, y, z))  # type: ignore[arg-type]  # no line
        except FormatError as err:
            raise FormatError(
                quats.path, None, f"image {getattr(image, 'name', '?')!r}: {err.message}"
            ) from None
    return matrix


#: largest COLMAP model file handed to pycolmap (bytes; points3D of big models is large)
MAX_MODEL_FILE_BYTES = 8 * 1024**3


def _check_model_files(model_dir: Path) -> None:
    """Every model file present is a regular file of bounded size (pycolmap would block on a
    FIFO or read a device without end)."""
    for name in MODEL_FILES:
        for ext in ("txt", "bin"):
            file = model_dir / f"{name}.{ext}"
            if os.path.lexists(file):
                size = regular_file_size(file, "COLMAP model file")
                if size > MAX_MODEL_FILE_BYTES:
                    raise InputError(
                        f"{file}: COLMAP model file of {size} bytes, more than the "
                        f"{MAX_MODEL_FILE_BYTES} read at most"
                    )


def load_model(model_dir: Path) -> tuple[Any, dict[int, Camera]]:
    """(pycolmap.Reconstruction, Camera by camera id) of a model directory."""
    try:
        import pycolmap
    except ImportError as err:
        raise InputError("reading COLMAP models needs pycolmap: pip install pycolmap") from err
    _check_model_files(model_dir)
    try:
        reconstruction = pycolmap.Reconstruction(str(model_dir))
    except (RuntimeError, ValueError, OSError, IndexError, KeyError) as err:
        message = " ".join(str(err).split())
        what = (
            "a consistent COLMAP model (each image's camera among the cameras)"
            if isinstance(err, (IndexError, KeyError)) else "a readable COLMAP model"
        )
        raise FormatError(model_dir, None, f"expected {what}; pycolmap failed: {message}") from None
    cameras_file = next(
        model_dir / f"cameras.{e}" for e in ("txt", "bin") if (model_dir / f"cameras.{e}").is_file()
    )
    lines = _camera_lines(cameras_file) if cameras_file.suffix == ".txt" else {}
    cameras: dict[int, Camera] = {}
    for camera_id, cam in reconstruction.cameras.items():
        model = cam.model.name if hasattr(cam.model, "name") else str(cam.model)
        line = lines.get(camera_id)
        if not (0 < cam.width <= MAX_CAMERA_SIDE and 0 < cam.height <= MAX_CAMERA_SIDE):
            # pycolmap reads a negative size of cameras.txt as a huge unsigned number
            raise FormatError(cameras_file, line, f"camera {camera_id}: expected a positive "
                              f"image size of at most {MAX_CAMERA_SIDE} px; got "
                              f"{_signed(cam.width)}x{_signed(cam.height)}")
        cameras[camera_id] = camera_from_colmap(
            cameras_file, line, model, cam.width, cam.height, [float(p) for p in cam.params]
        )
    return reconstruction, cameras


#: largest image side a COLMAP camera may have (px)
MAX_CAMERA_SIDE = 1 << 20


def _signed(value: int) -> int:
    """A size pycolmap read as unsigned 64 bits, as the signed number the file had."""
    return value - (1 << 64) if value >= 1 << 63 else value


def _camera_lines(path: Path) -> dict[int, int]:
    """Camera id -> its line number in a cameras.txt (to name the line of a bad camera)."""
    out: dict[int, int] = {}
    with open(path, "rb") as fh:  # a regular file of bounded size (``_check_model_files``)
        for i, row in enumerate(fh, start=1):
            head = row.split(None, 1)
            if head and not head[0].startswith(b"#"):
                try:
                    out.setdefault(int(head[0]), i)
                except ValueError:
                    continue
    return out


def cameras_by_image_name(path: str | Path) -> tuple[dict[str, Camera], list[Camera]]:
    """The Camera of every image of a COLMAP model (dir, file or project root) by image name,
    and every camera of the model (for images the model does not name)."""
    model_dir = colmap_model_dir(path)
    if model_dir is None:
        raise FormatError(path, None, "expected a COLMAP model with cameras.txt or cameras.bin")
    reconstruction, cameras = load_model(model_dir)
    by_name = {im.name: _camera_of(model_dir, cameras, im) for im in _images(reconstruction, model_dir)}
    return by_name, list(cameras.values())


def _images(reconstruction: Any, model_dir: Path) -> list[Any]:
    """The model's images; FormatError for an image name that is not UTF-8 (pycolmap raises
    UnicodeDecodeError on reading such a name)."""
    images = list(reconstruction.images.values())
    for im in images:
        try:
            im.name  # noqa: B018 - decoded on access
        except UnicodeDecodeError as err:
            raise FormatError(
                model_dir, None, f"expected UTF-8 image names; image {im.image_id} has bytes "
                f"that are not ({err.reason})"
            ) from None
    return images


def _camera_of(model_dir: Path, cameras: dict[int, Camera], image: Any) -> Camera:
    """The Camera of a pycolmap image; FormatError when its camera id is not in the model."""
    cam = cameras.get(image.camera_id)
    if cam is None:
        raise FormatError(
            model_dir, None, f"image {image.name!r} refers to camera id {image.camera_id}, which "
            f"the model does not have (cameras: {sorted(cameras)[:10]})"
        )
    return cam


def read_colmap(path: str | Path, *, images: str | Path | None = None) -> Trajectory:
    """Read a COLMAP model directory (or one of its files) into world_from_cam frames.

    frame_id and image_path are the image names; image files are resolved against ``images``
    (default: ``<model dir>/../images`` if it exists, else the model dir). Images without a pose
    are skipped with a WARNING; frames are sorted by name.
    """
    path = Path(path)
    if not path.exists():
        raise InputError(f"{path}: COLMAP model not found")
    model_dir = colmap_model_dir(path)
    if model_dir is None:
        raise FormatError(
            path,
            None,
            "expected a COLMAP model directory with cameras.txt or cameras.bin (or a project "
            "root with sparse/0/ or sparse/); got none",
        )
    reconstruction, cameras = load_model(model_dir)

    root = Path(images) if images is not None else default_images_dir(model_dir)
    if images is not None and not root.is_dir():
        raise InputError(f"{root}: images folder not found")
    frames: list[Frame] = []
    unposed: list[str] = []
    images_file = next(
        (model_dir / f"images.{e}" for e in ("txt", "bin") if (model_dir / f"images.{e}").is_file()),
        model_dir,
    )
    quats = QuaternionCounter(images_file)
    for image in _images(reconstruction, model_dir):
        check_frame_id(images_file, None, image.name, where=f"image id {image.image_id}",
                       what="image name")
        if not getattr(image, "has_pose", True):
            unposed.append(image.name)
            continue
        world_from_cam = invert_rigid(_cam_from_world(image, quats))
        frames.append(
            Frame(
                frame_id=image.name,
                camera=_camera_of(model_dir, cameras, image),
                world_from_cam=world_from_cam,
                image_path=image.name,
                image_file=root / image.name,
            )
        )
    quats.report()
    if unposed:
        logger.warning(
            "%s: skipped %d image(s) without a pose (first: %s)",
            model_dir,
            len(unposed),
            unposed[0],
        )
    if not frames:
        raise FormatError(model_dir, None, "expected at least one posed image; got none")
    frames.sort(key=lambda f: f.frame_id)
    logger.info("read %d frames from COLMAP model %s", len(frames), model_dir)
    return Trajectory(
        tuple(frames), source=str(model_dir), format="colmap", metadata={"images_dir": str(root)}
    )
