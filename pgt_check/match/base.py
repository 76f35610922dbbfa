"""The matcher interface every backend implements."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np

from pgt_check.types import check_shape


@dataclass(frozen=True, eq=False)
class Matches:
    """Correspondences in OpenCV pixel coordinates of the images that were passed in.

    kpts0: (N, 2) float64 in image0 (the render); kpts1: (N, 2) float64 in image1 (the photo);
    scores: (N,) float64, higher is better (1 for matchers without a score).
    n_kpts0 / n_kpts1: keypoints detected before matching.
    """

    kpts0: np.ndarray
    kpts1: np.ndarray
    scores: np.ndarray
    n_kpts0: int = 0
    n_kpts1: int = 0

    def __post_init__(self) -> None:
        k0 = np.asarray(self.kpts0, dtype=np.float64).reshape(-1, 2)
        k1 = np.asarray(self.kpts1, dtype=np.float64).reshape(-1, 2)
        s = np.asarray(self.scores, dtype=np.float64).reshape(-1)
        check_shape("kpts1", k1, (k0.shape[0], 2))
        check_shape("scores", s, (k0.shape[0],))
        object.__setattr__(self, "kpts0", k0)
        object.__setattr__(self, "kpts1", k1)
        object.__setattr__(self, "scores", s)

    def __len__(self) -> int:
        return int(self.kpts0.shape[0])

    @classmethod
    def empty(cls) -> Matches:
        return cls(np.zeros((0, 2)), np.zeros((0, 2)), np.zeros(0))


class Matcher(Protocol):
    """Finds correspondences between two RGB float32 [0, 1] images of shape (H, W, 3)."""

    name: str

    def match(self, image0: np.ndarray, image1: np.ndarray, mask0: np.ndarray | None = None) -> Matches:
        """Match image0 (render) to image1 (photo); mask0 (H, W) bool limits image0 keypoints."""
        ...
