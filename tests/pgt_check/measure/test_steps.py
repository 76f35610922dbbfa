"""The checker's stateless steps (``measure.steps``): matching at the enhancement's detail
size. The enhance decision, the edges-decisive rule and the clock are tested through
``FrameChecker`` in test_checker.py."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from pgt_check.config import HomographyConfig
from pgt_check.match.opencv import OpenCVMatcher
from pgt_check.measure.steps import Clock, match_path
from pgt_check.types import Camera

SHIFT = (6.0, -4.0)  # px, working = original size here


def _pair() -> tuple[np.ndarray, np.ndarray]:
    """A textured 640 x 480 image with detail at every scale and its copy shifted by SHIFT."""
    rng = np.random.default_rng(0)
    img = np.zeros((480, 640), np.float32)
    for size in (2, 6, 18, 54):
        noise = rng.random((480 // size + 2, 640 // size + 2)).astype(np.float32)
        img += cv2.resize(noise, (640 + 2 * size, 480 + 2 * size))[size:size + 480,
                                                                    size:size + 640]
    img = (img - img.min()) / (img.max() - img.min())
    m = np.float32([[1, 0, SHIFT[0]], [0, 1, SHIFT[1]]])
    photo = cv2.warpAffine(img, m, (640, 480), borderMode=cv2.BORDER_REFLECT)
    return np.repeat(img[..., None], 3, 2), np.repeat(photo[..., None], 3, 2)


@pytest.mark.parametrize("short_side", [160, 240])
def test_matching_at_the_detail_size_measures_in_working_and_original_pixels(short_side):
    render, photo = _pair()
    cam = Camera.pinhole(640, 480, 500, 500, 319.5, 239.5)
    args = (OpenCVMatcher(), HomographyConfig(), render, photo, np.ones((480, 640), bool),
            (640, 480), (1.0, 1.0), cam, Clock())
    full = match_path(*args)
    small = match_path(*args, short_side)
    assert full.success and small.success
    # both measure the same shift in original pixels (corner error = its length)
    assert full.corner_error_px == pytest.approx(np.hypot(*SHIFT), abs=0.5)
    assert small.corner_error_px == pytest.approx(np.hypot(*SHIFT), abs=1.5)
    # keypoints come back in working pixels: the render's inliers lie SHIFT from the photo's
    k0, k1 = small.kpts_render[small.inliers], small.kpts_photo[small.inliers]
    assert k0[:, 0].max() > 0.8 * 640 * short_side / 480  # beyond the small image's width
    assert np.median(k1 - k0, axis=0) == pytest.approx(SHIFT, abs=1.5)


def test_no_smaller_detail_size_is_plain_matching():
    render, photo = _pair()
    cam = Camera.pinhole(640, 480, 500, 500, 319.5, 239.5)
    args = (OpenCVMatcher(), HomographyConfig(), render, photo, np.ones((480, 640), bool),
            (640, 480), (1.0, 1.0), cam, Clock())
    plain = match_path(*args)
    for side in (None, 480, 1000):
        same = match_path(*args, side)
        assert same.n_matches == plain.n_matches
        assert same.corner_error_px == pytest.approx(plain.corner_error_px)
