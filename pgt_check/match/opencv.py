"""Classical OpenCV matchers: SIFT (default), ORB, AKAZE with ratio test and mutual check."""

from __future__ import annotations

import hashlib
import logging
import threading
from collections import OrderedDict
from dataclasses import dataclass

import numpy as np

from pgt_check.match.base import Matches
from pgt_check.types import check_shape

logger = logging.getLogger(__name__)

OPENCV_METHODS = ("sift", "orb", "akaze")

#: photos whose features are kept per process (keyed by the grey image's content and the
#: detector settings): the raw and enhanced paths of a frame, the registration refinement's
#: rounds, the per-frame corrections and the report's re-measured panels match the same photos
#: again (issue #28). 32 entries hold the refinement's 30 frames; about 1 MB each at 2,000
#: SIFT keypoints (2 MB at the 4,096 cap).
PHOTO_CACHE_SIZE = 32
_PHOTO_FEATURES: OrderedDict[tuple, tuple[np.ndarray, np.ndarray | None]] = OrderedDict()
_PHOTO_LOCK = threading.Lock()


def clear_photo_cache() -> None:
    """Forget the cached photo features (tests, or to free memory)."""
    with _PHOTO_LOCK:
        _PHOTO_FEATURES.clear()


def to_gray_u8(image: np.ndarray) -> np.ndarray:
    """(H, W, 3) RGB float32 [0, 1] (or (H, W)) -> (H, W) uint8 grey."""
    import cv2

    image = np.asarray(image)
    if image.ndim == 3:
        check_shape("image", image, (None, None, 3))
        if image.dtype != np.uint8:
            image = (np.clip(image, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)
        return cv2.cvtColor(image, cv2.COLOR_RGB2GRAY)
    check_shape("image", image, (None, None))
    if image.dtype != np.uint8:
        image = (np.clip(image, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)
    return image


@dataclass
class OpenCVMatcher:
    """Detect + describe with an OpenCV feature, match with Lowe's ratio test + mutual check.

    method: "sift" | "orb" | "akaze"; max_keypoints: cap per image (strongest kept);
    ratio: Lowe's ratio; mutual: keep only matches that are each other's nearest neighbour;
    clahe: equalise local contrast of both images first (renders and photos differ in exposure
    and contrast; on the 7-Scenes frames this raised the share of frames with a valid
    homography from 0.70 to 0.90); rootsift: Hellinger-normalised SIFT descriptors.
    """

    method: str = "sift"
    max_keypoints: int = 4096
    ratio: float = 0.9
    mutual: bool = True
    clahe: bool = True
    rootsift: bool = True

    def __post_init__(self) -> None:
        if self.method not in OPENCV_METHODS:
            raise ValueError(f"unknown OpenCV method {self.method!r} (allowed: {OPENCV_METHODS})")
        if not 0.0 < self.ratio <= 1.0:
            raise ValueError(f"ratio must be in (0, 1], got {self.ratio}")
        self.name = self.method
        self._detector = None

    def _detector_and_norm(self):
        import cv2

        if self._detector is None:
            if self.method == "sift":
                det, norm = cv2.SIFT_create(nfeatures=self.max_keypoints), cv2.NORM_L2
            elif self.method == "orb":
                det, norm = cv2.ORB_create(nfeatures=self.max_keypoints), cv2.NORM_HAMMING
            else:
                # OpenCV 5 moved AKAZE into the contrib module xfeatures2d
                create = getattr(cv2, "AKAZE_create", None) or cv2.xfeatures2d.AKAZE_create
                det, norm = create(threshold=1e-4), cv2.NORM_HAMMING
            self._detector = (det, norm)
        return self._detector

    def _detect(self, gray: np.ndarray, mask: np.ndarray | None):
        import cv2

        det, _ = self._detector_and_norm()
        if self.clahe:
            gray = cv2.createCLAHE(clipLimit=2.0, tileGridSize=(8, 8)).apply(gray)
        m = None if mask is None else mask.astype(np.uint8) * 255
        kpts, desc = det.detectAndCompute(gray, m)
        if desc is None or len(kpts) == 0:
            return np.zeros((0, 2)), None
        if len(kpts) > self.max_keypoints:
            order = np.argsort([-k.response for k in kpts])[: self.max_keypoints]
            kpts = [kpts[i] for i in order]
            desc = desc[order]
        if self.method == "sift" and self.rootsift:
            desc = np.sqrt(desc / (desc.sum(axis=1, keepdims=True) + 1e-7)).astype(np.float32)
        return np.array([k.pt for k in kpts], dtype=np.float64), desc

    def _photo_features(self, image1: np.ndarray):
        """Features of the photo, computed once per photo content and detector settings
        (``PHOTO_CACHE_SIZE``, least recently used dropped first): detection is deterministic
        in the grey image, so a cached result is the one a new detection would give."""
        gray = to_gray_u8(image1)
        key = (self.method, self.max_keypoints, self.clahe, self.rootsift, gray.shape,
               hashlib.blake2b(np.ascontiguousarray(gray).data, digest_size=16).digest())
        with _PHOTO_LOCK:
            feats = _PHOTO_FEATURES.get(key)
            if feats is not None:
                _PHOTO_FEATURES.move_to_end(key)
                return feats
        feats = self._detect(gray, None)
        for a in feats:
            if a is not None:
                a.setflags(write=False)  # shared between calls: never modified in place
        with _PHOTO_LOCK:
            _PHOTO_FEATURES[key] = feats
            while len(_PHOTO_FEATURES) > PHOTO_CACHE_SIZE:
                _PHOTO_FEATURES.popitem(last=False)
        return feats

    def __getstate__(self) -> dict:
        """Pickles without OpenCV objects or cached features (rebuilt on first use)."""
        state = dict(self.__dict__)
        state["_detector"] = None
        return state

    def match(
        self, image0: np.ndarray, image1: np.ndarray, mask0: np.ndarray | None = None
    ) -> Matches:
        """Match image0 (render) to image1 (photo); both (H, W, 3) RGB float32 in [0, 1]."""
        import cv2

        g0 = to_gray_u8(image0)
        if mask0 is not None:
            check_shape("mask0", np.asarray(mask0), g0.shape)
        k0, d0 = self._detect(g0, mask0)
        k1, d1 = self._photo_features(image1)
        if d0 is None or d1 is None or len(k0) < 2 or len(k1) < 2:
            return Matches(np.zeros((0, 2)), np.zeros((0, 2)), np.zeros(0), len(k0), len(k1))
        _, norm = self._detector_and_norm()
        bf = cv2.BFMatcher(norm)
        knn = bf.knnMatch(d0, d1, k=2)
        q0: list[int] = []
        q1: list[int] = []
        qd: list[float] = []
        for pair in knn:
            if len(pair) < 2:
                continue
            m, second = pair
            if m.distance < self.ratio * second.distance:
                q0.append(m.queryIdx)
                q1.append(m.trainIdx)
                qd.append(m.distance)
        i0, i1, dist = np.array(q0, int), np.array(q1, int), np.array(qd, float)
        if self.mutual and len(i0):
            back = bf.match(d1, d0)
            nn10 = np.full(len(k1), -1)
            for m in back:
                nn10[m.queryIdx] = m.trainIdx
            keep = nn10[i1] == i0
            i0, i1, dist = i0[keep], i1[keep], dist[keep]
        scores = 1.0 / (1.0 + dist) if len(dist) else np.zeros(0)
        return Matches(k0[i0], k1[i1], scores, len(k0), len(k1))
