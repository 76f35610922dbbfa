"""Deterministic image pairs for the LPIPS reference fixture (numpy only, shared by the test and
by fixtures/make_lpips_reference.py, which runs lpips-jax in a throwaway venv)."""

from __future__ import annotations

import numpy as np

SIZE = 64


def _box_upsample(x: np.ndarray, f: int) -> np.ndarray:
    return np.repeat(np.repeat(x, f, axis=0), f, axis=1)


def make_pairs(seed: int = 1234) -> list[tuple[np.ndarray, np.ndarray]]:
    """Four (a, b) pairs of float32 (64, 64, 3) RGB images in [0, 1]."""
    rng = np.random.default_rng(seed)
    pairs = []
    # 0: uniform noise vs the same plus Gaussian noise (sigma 0.1), clipped.
    a = rng.random((SIZE, SIZE, 3))
    pairs.append((a, np.clip(a + 0.1 * rng.standard_normal(a.shape), 0, 1)))
    # 1: two independent uniform-noise images.
    pairs.append((rng.random((SIZE, SIZE, 3)), rng.random((SIZE, SIZE, 3))))
    # 2: 8x8-blocky noise vs the same rolled by 3 px right / 2 px down.
    a = _box_upsample(rng.random((SIZE // 8, SIZE // 8, 3)), 8)
    pairs.append((a, np.roll(a, (2, 3), axis=(0, 1))))
    # 3: smooth colour gradient vs its gamma-adjusted (x ** 1.5) copy with a dark square.
    yy, xx = np.mgrid[0:SIZE, 0:SIZE] / (SIZE - 1)
    a = np.stack([xx, yy, 0.5 * (xx + yy)], axis=-1)
    b = a**1.5
    b[16:40, 20:44] = 0.1
    pairs.append((a, b))
    return [(x.astype(np.float32), y.astype(np.float32)) for x, y in pairs]
