import numpy as np
import pytest

from pgt_check.match import MATCHERS, make_matcher
from pgt_check.match.base import Matches


def _textured(seed=0, h=240, w=320):
    import cv2

    rng = np.random.default_rng(seed)
    img = rng.uniform(0, 1, size=(h // 8, w // 8, 3)).astype(np.float32)
    img = cv2.resize(img, (w, h), interpolation=cv2.INTER_CUBIC)
    return np.clip(img, 0, 1)


@pytest.mark.parametrize("name", ["sift", "orb", "akaze"])
def test_matcher_recovers_pure_translation(name):
    img = _textured()
    shifted = np.roll(img, shift=(5, 7), axis=(0, 1))
    m = make_matcher(name).match(img, shifted)
    assert len(m) >= 20
    d = m.kpts1 - m.kpts0
    # most matches agree with the known shift (+7 px in x, +5 px in y), ignoring wrap-around
    good = np.linalg.norm(d - [7, 5], axis=1) < 1.5
    assert good.mean() > 0.8
    assert m.kpts0.dtype == np.float64 and m.scores.shape == (len(m),)


def test_mask_limits_render_keypoints():
    img = _textured(1)
    mask = np.zeros(img.shape[:2], bool)
    mask[:, : img.shape[1] // 2] = True
    m = make_matcher("sift").match(img, img, mask0=mask)
    assert len(m) > 10
    assert np.all(m.kpts0[:, 0] < img.shape[1] // 2 + 2)


def test_blank_images_give_no_matches():
    blank = np.zeros((64, 64, 3), np.float32)
    m = make_matcher("sift").match(blank, blank)
    assert len(m) == 0 and m.kpts0.shape == (0, 2)


def test_unknown_matcher_names_available_ones():
    with pytest.raises(ValueError, match="sift"):
        make_matcher("nope")
    assert {"sift", "orb", "akaze"} <= set(MATCHERS)


def test_matches_shape_check():
    with pytest.raises(ValueError, match="kpts1"):
        Matches(np.zeros((3, 2)), np.zeros((2, 2)), np.zeros(3))


def test_mutual_check_reduces_matches_on_repetitive_pattern():
    # a repetitive texture creates ambiguous matches; the mutual check must not keep more
    tile = _textured(3, 32, 32)
    img = np.tile(tile, (6, 8, 1))
    a = make_matcher("sift", mutual=False, ratio=1.0).match(img, img)
    b = make_matcher("sift", mutual=True, ratio=1.0).match(img, img)
    assert len(b) <= len(a)


def test_photo_features_are_computed_once_per_content_and_settings(monkeypatch):
    """The refinement rounds, corrections and re-measured panels match the same photos again:
    their features come from the per-process cache (same content, same settings), and the
    matches are those of a fresh detection (issue #28)."""
    from pgt_check.match import opencv

    opencv.clear_photo_cache()
    photo, render = _textured(3), np.roll(_textured(3), shift=(2, 3), axis=(0, 1))
    calls = []
    real = opencv.OpenCVMatcher._detect

    def counting(self, gray, mask):
        calls.append(mask is None)  # True: a photo detection
        return real(self, gray, mask)

    monkeypatch.setattr(opencv.OpenCVMatcher, "_detect", counting)
    mask = np.ones(render.shape[:2], bool)  # the render is detected under its coverage mask
    first = opencv.OpenCVMatcher().match(render, photo, mask0=mask)
    again = opencv.OpenCVMatcher().match(render, photo.copy(), mask0=mask)  # a new checker
    assert calls.count(True) == 1 and calls.count(False) == 2
    np.testing.assert_array_equal(first.kpts0, again.kpts0)
    np.testing.assert_array_equal(first.kpts1, again.kpts1)
    opencv.OpenCVMatcher(max_keypoints=500).match(render, photo, mask0=mask)  # other settings
    opencv.OpenCVMatcher().match(render, np.clip(photo * 0.5, 0, 1), mask0=mask)  # content
    assert calls.count(True) == 3
    opencv.clear_photo_cache()
