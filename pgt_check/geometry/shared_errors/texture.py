"""Mesh colours against mesh geometry: the offset between where texture matches and where
geometric edges place the photos, shared by the frames.

A mesh coloured from the same photos placed with the same poses carries those poses' shared
error (a calibration offset) in its colours: texture matches then find the poses right while
the geometry shows the error. Per frame, the median residual (photo - projection of the lifted
render point, at the checked pose) of the texture points minus that of the geometric points is
one 2D offset; the run's offset is the per-component median over frames, with a bootstrap
interval over frames.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from pgt_check.types import check_shape


@dataclass(frozen=True)
class FramePoints:
    """One frame's texture and geometric correspondences: photo pixels (n, 2) and the lifted
    render points in the checked camera's frame (n, 3), with the photo intrinsics K (3, 3)."""

    K: np.ndarray
    texture_2d: np.ndarray
    texture_cam: np.ndarray
    geometry_2d: np.ndarray
    geometry_cam: np.ndarray


@dataclass(frozen=True)
class TextureOffset:
    """offset_px: (dx, dy) texture minus geometry, px (median over frames); effect_px: its
    length, with a 95 % bootstrap interval; per_frame: (F, 2) offsets of the frames used."""

    success: bool
    reason: str
    n_frames: int
    offset_px: tuple[float, float] = (float("nan"), float("nan"))
    effect_px: float = float("nan")
    effect_px_ci: tuple[float, float] = (float("nan"), float("nan"))
    per_frame: np.ndarray | None = None


def _residual(k: np.ndarray, pts2d: np.ndarray, pts_cam: np.ndarray) -> np.ndarray:
    """Median (2,) of photo - projection over the points."""
    check_shape("pts2d", pts2d, (None, 2))
    check_shape("pts_cam", pts_cam, (None, 3))
    z = pts_cam[:, 2]
    ok = np.isfinite(z) & (z > 0) & np.all(np.isfinite(pts2d), axis=1)
    u = pts_cam[ok] @ k.T
    return np.median(pts2d[ok] - u[:, :2] / u[:, 2:], axis=0)


def texture_offset(
    frames: Sequence[FramePoints],
    *,
    min_texture_points: int = 8,
    min_geometry_points: int = 20,
    min_frames: int = 5,
    n_bootstrap: int = 200,
    seed: int = 0,
) -> TextureOffset:
    """The offset of texture evidence against geometric evidence shared by the frames.

    Frames need ``min_texture_points`` texture and ``min_geometry_points`` geometric points;
    fewer than ``min_frames`` such frames give ``success=False`` (reason ``too_few_frames``).
    """
    per = []
    for f in frames:
        k = np.asarray(f.K, np.float64)
        check_shape("K", k, (3, 3))
        t2, t3 = np.asarray(f.texture_2d, np.float64), np.asarray(f.texture_cam, np.float64)
        g2, g3 = np.asarray(f.geometry_2d, np.float64), np.asarray(f.geometry_cam, np.float64)
        if len(t2) < min_texture_points or len(g2) < min_geometry_points:
            continue
        d = _residual(k, t2, t3) - _residual(k, g2, g3)
        if np.all(np.isfinite(d)):
            per.append(d)
    if len(per) < min_frames:
        return TextureOffset(False, "too_few_frames", len(per))
    off = np.asarray(per)
    est = np.median(off, axis=0)
    rng = np.random.default_rng(seed)
    idx = rng.integers(0, len(off), size=(n_bootstrap, len(off)))
    boot = np.linalg.norm(np.median(off[idx], axis=1), axis=1)
    lo, hi = np.percentile(boot, [2.5, 97.5])
    return TextureOffset(
        True,
        "",
        len(off),
        (float(est[0]), float(est[1])),
        float(np.linalg.norm(est)),
        (float(lo), float(hi)),
        off,
    )
