"""Image loading at the package edge: HxWx3 RGB float32 in [0, 1].

Pixels are read as stored: EXIF orientation tags are ignored, as COLMAP and the pose files
refer to the stored pixel grid.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from pgt_check.common.files import read_bytes_limited, regular_file_size
from pgt_check.errors import InputError, PixelCapError

logger = logging.getLogger(__name__)

#: file extensions treated as images when scanning a folder
IMAGE_EXTENSIONS = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".ppm", ".pgm", ".webp")

#: default cap on the pixels an image may declare (width x height), checked on the header
#: before decoding: a decoded RGB float32 image takes 12 bytes per pixel plus the 8-bit buffer,
#: so 100 MP bound one frame's photo at ~1.5 GB per worker
DEFAULT_MAX_IMAGE_PIXELS = 100_000_000

#: bytes an image file may have per pixel of the cap (uncompressed 16-bit RGBA) plus room for
#: its metadata: a bigger file is refused before it is read
MAX_BYTES_PER_PIXEL = 8
MAX_METADATA_BYTES = 16 * 1024**2
#: the largest image file read at all (OpenCV decodes at most 2 GiB buffers)
MAX_IMAGE_FILE_BYTES = 2**31 - 1


def image_byte_limit(max_pixels: int | None) -> int:
    """The largest image file read for a pixel cap of ``max_pixels`` (None = no cap)."""
    if max_pixels is None:
        return MAX_IMAGE_FILE_BYTES
    return min(MAX_IMAGE_FILE_BYTES, MAX_BYTES_PER_PIXEL * max_pixels + MAX_METADATA_BYTES)


def check_pixel_cap(path: str | Path, max_pixels: int | None) -> None:
    """Raise PixelCapError if the header of ``path`` declares more than ``max_pixels`` pixels.

    Reads only the header (PIL, lazy). A file PIL cannot identify is left to the decoder (which
    then fails or decodes a format PIL lacks; OpenCV keeps its own 2^30-pixel limit)."""
    if max_pixels is None:
        return
    from PIL import Image

    pil_limit = Image.MAX_IMAGE_PIXELS
    Image.MAX_IMAGE_PIXELS = None  # this cap replaces PIL's bomb check (header only here)
    try:
        with Image.open(path) as im:
            width, height = im.size
    except Exception:  # noqa: BLE001 - unidentifiable header: the decoder decides
        return
    finally:
        Image.MAX_IMAGE_PIXELS = pil_limit
    if int(width) * int(height) > max_pixels:
        raise PixelCapError(
            f"{path}: image declares {width}x{height} = {int(width) * int(height)} pixels, "
            f"more than the cap of {max_pixels} (--max-image-pixels)"
        )


def load_image(path: str | Path, max_pixels: int | None = DEFAULT_MAX_IMAGE_PIXELS) -> np.ndarray:
    """Read an image as (H, W, 3) float32 RGB in [0, 1].

    8- and 16-bit integer images are scaled by their type's maximum; grayscale is repeated to
    three channels; an alpha channel is dropped. Raises InputError if the file is missing or
    cannot be decoded or is not a regular file, PixelCapError (before reading) if the file is
    larger than ``image_byte_limit(max_pixels)`` or its header declares more than ``max_pixels``
    pixels (None = no pixel cap; the file size is still bounded).
    """
    import cv2  # heavy: imported on first use

    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: image not found")
    limit = image_byte_limit(max_pixels)
    size = regular_file_size(path, "image")
    if size > limit:
        raise PixelCapError(
            f"{path}: image file of {size} bytes is larger than the {limit} bytes read for "
            f"images of at most {max_pixels} pixels (--max-image-pixels)"
        )
    check_pixel_cap(path, max_pixels)
    # read as bytes (works for non-ASCII paths, unlike imread), bounded while reading too
    data = np.frombuffer(read_bytes_limited(path, limit, "image"), dtype=np.uint8)
    try:
        image = cv2.imdecode(data, cv2.IMREAD_UNCHANGED) if data.size else None
    except cv2.error as err:
        raise InputError(f"{path}: cannot decode image ({' '.join(str(err).split())[:160]})"
                         ) from None
    if image is None:
        raise InputError(f"{path}: cannot decode image (unsupported or corrupt file)")
    if image.ndim == 3 and image.shape[2] == 1:
        image = image[:, :, 0]
    if image.ndim == 2:
        image = np.repeat(image[:, :, None], 3, axis=2)
    elif image.shape[2] == 4:
        image = cv2.cvtColor(image, cv2.COLOR_BGRA2RGB)
    elif image.shape[2] == 3:
        image = cv2.cvtColor(image, cv2.COLOR_BGR2RGB)
    else:
        raise InputError(f"{path}: expected 1, 3 or 4 channels; got {image.shape[2]}")
    if np.issubdtype(image.dtype, np.integer):
        out = image.astype(np.float32) / np.float32(np.iinfo(image.dtype).max)  # type: ignore[operator, type-var]
    else:
        out = np.clip(np.nan_to_num(image.astype(np.float32)), 0.0, 1.0)
    return np.ascontiguousarray(out)


def image_size(path: str | Path) -> tuple[int, int]:
    """(width, height) of an image from its header (no decoding); InputError if unreadable."""
    from PIL import Image, UnidentifiedImageError

    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: image not found")
    try:
        with Image.open(path) as im:
            width, height = im.size
    except (UnidentifiedImageError, OSError) as err:
        raise InputError(f"{path}: cannot read image header ({err})") from err
    return int(width), int(height)


def resize_image(
    image: np.ndarray, size: tuple[int, int], interpolation: str = "area"
) -> np.ndarray:
    """Resize an (H, W[, C]) image to ``size`` = (width, height).

    interpolation: "area" (default; right for shrinking), "linear" or "cubic" (for enlarging).
    Returns the input itself when it already has that size.
    """
    import cv2

    flags = {"area": cv2.INTER_AREA, "linear": cv2.INTER_LINEAR, "cubic": cv2.INTER_CUBIC}
    if interpolation not in flags:
        raise ValueError(f"interpolation must be one of {sorted(flags)}, got {interpolation!r}")
    if (image.shape[1], image.shape[0]) == tuple(size):
        return image
    return cv2.resize(image, tuple(size), interpolation=flags[interpolation])
