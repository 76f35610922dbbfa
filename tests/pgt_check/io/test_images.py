from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest
from numpy.testing import assert_allclose

from pgt_check.errors import InputError
from pgt_check.io import image_size, load_image


def test_color_png_is_rgb_float(tmp_path: Path) -> None:
    bgr = np.zeros((4, 6, 3), np.uint8)
    bgr[..., 2] = 255  # red in OpenCV's BGR order
    bgr[0, 0] = (0, 51, 0)
    cv2.imwrite(str(tmp_path / "a.png"), bgr)
    image = load_image(tmp_path / "a.png")
    assert image.shape == (4, 6, 3) and image.dtype == np.float32
    assert_allclose(image[1, 1], [1.0, 0.0, 0.0])
    assert_allclose(image[0, 0], [0.0, 0.2, 0.0], atol=1e-7)


def test_grayscale_16bit_and_alpha(tmp_path: Path) -> None:
    gray = np.full((3, 5), 65535 // 2, np.uint16)
    cv2.imwrite(str(tmp_path / "g16.png"), gray)
    image = load_image(tmp_path / "g16.png")
    assert image.shape == (3, 5, 3)
    assert_allclose(image, (65535 // 2) / 65535, atol=1e-6)
    bgra = np.zeros((2, 2, 4), np.uint8)
    bgra[..., 0] = 255  # blue
    bgra[..., 3] = 10
    cv2.imwrite(str(tmp_path / "a.png"), bgra)
    assert_allclose(load_image(tmp_path / "a.png")[0, 0], [0.0, 0.0, 1.0])
    gray8 = np.arange(6, dtype=np.uint8).reshape(2, 3) * 50
    cv2.imwrite(str(tmp_path / "g8.jpg"), gray8, [cv2.IMWRITE_JPEG_QUALITY, 100])
    out = load_image(tmp_path / "g8.jpg")
    assert out.shape == (2, 3, 3)
    assert_allclose(out[..., 0], out[..., 2])


def test_missing_and_corrupt(tmp_path: Path) -> None:
    with pytest.raises(InputError, match="not found"):
        load_image(tmp_path / "nope.png")
    (tmp_path / "bad.png").write_bytes(b"not an image")
    with pytest.raises(InputError, match="cannot decode"):
        load_image(tmp_path / "bad.png")
    (tmp_path / "empty.png").write_bytes(b"")
    with pytest.raises(InputError, match="cannot decode"):
        load_image(tmp_path / "empty.png")
    with pytest.raises(InputError, match="cannot read image header"):
        image_size(tmp_path / "bad.png")
    with pytest.raises(InputError, match="not found"):
        image_size(tmp_path / "nope.png")


def test_image_size(tmp_path: Path, make_image) -> None:
    assert image_size(make_image(tmp_path / "a.png", 37, 21)) == (37, 21)


@pytest.mark.shared_data
def test_real_jpeg(shared_data: Path) -> None:
    path = shared_data / "7scenes_redkitchen" / "images" / "frame-000000.color.jpg"
    assert image_size(path) == (640, 480)
    image = load_image(path)
    assert image.shape == (480, 640, 3) and 0.0 <= image.min() and image.max() <= 1.0
