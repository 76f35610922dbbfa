"""Drawn test scenes of the edge evidence (no renderer, exact answers): analytic depth maps of
fronto-parallel blocks and 'photos' whose intensity edges are the depth edges, warped by a known
homography. Shared by the tests of ``pgt_check.geometry.edges`` (imported by its module path)."""

from __future__ import annotations

import cv2
import numpy as np

from pgt_check.geometry.homography import apply_homography, image_corners

W, H = 320, 240
K = np.array([[260.0, 0, (W - 1) / 2], [0, 260.0, (H - 1) / 2], [0, 0, 1]])


def corner_distance(h1: np.ndarray, h2: np.ndarray, w: int = W, h: int = H) -> float:
    """Mean distance between the image corners mapped by two homographies (px)."""
    c = image_corners(w, h)
    return float(np.mean(np.linalg.norm(apply_homography(h1, c) - apply_homography(h2, c), axis=1)))


def blocks_depth(seed: int = 0, n: int = 7) -> np.ndarray:
    """A back plane at 4 m with fronto-parallel rectangles at 1.5-3 m (varied sizes)."""
    rng = np.random.default_rng(seed)
    z = np.full((H, W), 4.0, dtype=np.float32)
    for _ in range(n):
        w, h = rng.integers(25, 80, 2)
        x, y = rng.integers(10, W - w - 10), rng.integers(10, H - h - 10)
        z[y : y + h, x : x + w] = rng.uniform(1.5, 3.0)
    return z


def photo_from_depth(z: np.ndarray, warp: np.ndarray | None = None, seed: int = 0) -> np.ndarray:
    """A 'photo' whose intensity edges are the depth edges: grey levels by depth, rendered 4x
    larger and area-averaged (anti-aliased sub-pixel edges), warped by ``warp`` (photo_from_render,
    3x3), blurred, noisy."""
    rng = np.random.default_rng(seed)
    levels = np.unique(z)
    grey = rng.uniform(0.15, 0.85, len(levels))
    img = grey[np.searchsorted(levels, z)].astype(np.float32)
    s = 4
    big = cv2.resize(img, (W * s, H * s), interpolation=cv2.INTER_NEAREST)
    up = np.array([[s, 0, (s - 1) / 2], [0, s, (s - 1) / 2], [0, 0, 1.0]])  # x_big = s x + ..
    h = np.eye(3) if warp is None else np.asarray(warp, dtype=np.float64)
    big = cv2.warpPerspective(
        big,
        up @ h @ np.linalg.inv(up),
        (W * s, H * s),
        flags=cv2.INTER_LINEAR,
        borderMode=cv2.BORDER_REFLECT,
    )
    out = cv2.resize(big, (W, H), interpolation=cv2.INTER_AREA)
    out = cv2.GaussianBlur(out, (0, 0), 0.7) + rng.normal(0, 0.01, out.shape).astype(np.float32)
    return np.repeat(np.clip(out, 0, 1)[:, :, None], 3, axis=2)


def translation(dx: float, dy: float) -> np.ndarray:
    return np.array([[1, 0, dx], [0, 1, dy], [0, 0, 1.0]])
