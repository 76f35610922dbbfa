"""Distance transforms with labels (nearest edge pixel) for the photo edge maps."""

from __future__ import annotations

import numpy as np


def row_major_index(pixels: np.ndarray, width: int) -> np.ndarray:
    return pixels[:, 1].astype(np.int64) * width + pixels[:, 0].astype(np.int64)


def distance_with_labels(mask: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Distance to the nearest True pixel of ``mask``, its OpenCV label (from 1; 0 = none) and
    the row-major pixel index of each label - 1 (OpenCV numbers the zero pixels row-major)."""
    import cv2

    h, w = mask.shape
    order = np.flatnonzero(mask.ravel())
    if not len(order):
        return np.full((h, w), np.inf, np.float32), np.zeros((h, w), np.int32), order
    src = np.where(mask, 0, 255).astype(np.uint8)
    dist, labels = cv2.distanceTransformWithLabels(
        src, cv2.DIST_L2, 5, labelType=cv2.DIST_LABEL_PIXEL
    )
    return dist, labels, order
