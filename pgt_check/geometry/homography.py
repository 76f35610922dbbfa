"""Homography estimation between render and photo, its degeneracy guards, and the corner error.

The estimated homography is ``photo_from_render``: it maps render pixels to photo pixels (OpenCV
pixel convention). A correct pose gives the identity, whatever the scene's depth structure,
because render and photo then see every point at the same pixel.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from enum import Enum

import numpy as np

from pgt_check.config import HomographyConfig
from pgt_check.types import check_shape

logger = logging.getLogger(__name__)


class Reason(str, Enum):
    """Why a homography could not be used (machine-readable, closed set)."""

    TOO_FEW_MATCHES = "too_few_matches"
    TOO_FEW_INLIERS = "too_few_inliers"
    ESTIMATION_FAILED = "estimation_failed"
    NON_FINITE = "non_finite_homography"
    ILL_CONDITIONED = "ill_conditioned_homography"
    ORIENTATION_FLIP = "orientation_flip"
    DEGENERATE_MATCHES = "degenerate_matches"


@dataclass(frozen=True, eq=False)
class HomographyResult:
    """Result of ``estimate_homography``; ``photo_from_render`` is None unless ``success``."""

    success: bool
    reason: Reason | None
    photo_from_render: np.ndarray | None
    inliers: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=bool))

    @property
    def n_inliers(self) -> int:
        return int(self.inliers.sum())


def _failure(reason: Reason, n: int, inliers: np.ndarray | None = None) -> HomographyResult:
    mask = np.zeros(n, dtype=bool) if inliers is None else inliers
    return HomographyResult(False, reason, None, mask)


def image_corners(width: float, height: float) -> np.ndarray:
    """(4, 2) float64 outer corners of a width x height image in OpenCV pixel convention.

    The outer corners of the pixel grid are at -0.5 and size - 0.5.
    """
    x0, y0, x1, y1 = -0.5, -0.5, width - 0.5, height - 0.5
    return np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]], dtype=np.float64)


def apply_homography(h: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Map (N, 2) points by a (3, 3) homography. Points mapped to infinity come back non-finite."""
    h = np.asarray(h, dtype=np.float64)
    points = np.asarray(points, dtype=np.float64)
    check_shape("homography", h, (3, 3))
    check_shape("points", points, (None, 2))
    ph = np.concatenate([points, np.ones((len(points), 1))], axis=1) @ h.T
    with np.errstate(divide="ignore", invalid="ignore"):
        return ph[:, :2] / ph[:, 2:3]


def _signed_area(quad: np.ndarray) -> float:
    x, y = quad[:, 0], quad[:, 1]
    return 0.5 * float(np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y))


def _is_convex(quad: np.ndarray) -> bool:
    d = np.roll(quad, -1, axis=0) - quad
    cross = d[:, 0] * np.roll(d, -1, axis=0)[:, 1] - d[:, 1] * np.roll(d, -1, axis=0)[:, 0]
    return bool(np.all(cross > 0) or np.all(cross < 0))


def check_homography(
    h: np.ndarray, width: float, height: float, config: HomographyConfig = HomographyConfig()
) -> Reason | None:
    """Return why ``h`` is unusable for a width x height image, or None if it is fine.

    Guards: non-finite entries; ill-conditioned (condition number of h normalised to the image
    frame above ``config.max_condition``); corners mapped through the line at infinity, a
    mirrored (orientation flip) or non-convex warped image; area change beyond
    ``config.max_area_ratio``.
    """
    h = np.asarray(h, dtype=np.float64)
    check_shape("homography", h, (3, 3))
    if not np.all(np.isfinite(h)):
        return Reason.NON_FINITE
    peak = float(np.abs(h).max())
    if peak > 0.0:
        h = h / peak  # scale-free: avoids overflow / denormals for huge or tiny entries
    # Condition number in normalised coordinates (image -> [-1, 1]^2) so it is size-independent.
    s = 2.0 / max(width, height)
    t = np.array([[s, 0, -1.0], [0, s, -1.0], [0, 0, 1]])
    hn = t @ h @ np.linalg.inv(t)
    try:
        sv = np.linalg.svd(hn, compute_uv=False)
    except np.linalg.LinAlgError:
        return Reason.ILL_CONDITIONED
    if sv[-1] <= 0 or sv[0] / sv[-1] > config.max_condition:
        return Reason.ILL_CONDITIONED
    corners = image_corners(width, height)
    w = np.concatenate([corners, np.ones((4, 1))], axis=1) @ h.T
    if not np.all(w[:, 2] > 0) and not np.all(w[:, 2] < 0):
        return Reason.ILL_CONDITIONED  # the image straddles the line at infinity
    warped = apply_homography(h, corners)
    if not np.all(np.isfinite(warped)):
        return Reason.NON_FINITE
    a0 = _signed_area(corners)
    a1 = _signed_area(warped)
    if a1 * a0 <= 0:
        return Reason.ORIENTATION_FLIP
    if not _is_convex(warped):
        return Reason.ORIENTATION_FLIP
    ratio = abs(a1 / a0)
    if ratio > config.max_area_ratio or ratio < 1.0 / config.max_area_ratio:
        return Reason.ILL_CONDITIONED
    return None


def _degenerate_points(points: np.ndarray) -> bool:
    """True if the points span (almost) no area: collinear, one cluster or duplicates."""
    if len(points) < 4:
        return True
    unique = np.unique(np.round(points, 3), axis=0)
    if len(unique) < 4:
        return True
    c = points - points.mean(axis=0)
    sv = np.linalg.svd(c, compute_uv=False)
    return bool(sv[1] < 1e-3 * max(sv[0], 1e-12) or sv[1] / np.sqrt(len(points)) < 0.5)


def estimate_homography(
    kpts_render: np.ndarray,
    kpts_photo: np.ndarray,
    width: float,
    height: float,
    config: HomographyConfig = HomographyConfig(),
) -> HomographyResult:
    """Robustly fit ``photo_from_render`` with OpenCV USAC MAGSAC++ and check it.

    kpts_render, kpts_photo: (N, 2) float64 pixel coordinates (OpenCV convention) of matched
    points; width, height: size of the render (for the guards). Never raises for bad data:
    failures come back as ``success=False`` with a ``Reason``.
    """
    import cv2

    kpts_render = np.asarray(kpts_render, dtype=np.float64).reshape(-1, 2)
    kpts_photo = np.asarray(kpts_photo, dtype=np.float64).reshape(-1, 2)
    check_shape("kpts_photo", kpts_photo, (len(kpts_render), 2))
    n = len(kpts_render)
    # finite as the float32 that OpenCV gets (1e300 is finite in float64, inf in float32)
    with np.errstate(over="ignore"):
        finite = np.all(np.isfinite(kpts_render.astype(np.float32)), axis=1) & np.all(
            np.isfinite(kpts_photo.astype(np.float32)), axis=1
        )
    if n < max(4, config.min_matches) or finite.sum() < max(4, config.min_matches):
        return _failure(Reason.TOO_FEW_MATCHES, n)
    if _degenerate_points(kpts_render[finite]) or _degenerate_points(kpts_photo[finite]):
        return _failure(Reason.DEGENERATE_MATCHES, n)
    try:
        h, mask = cv2.findHomography(
            kpts_render[finite].astype(np.float32),
            kpts_photo[finite].astype(np.float32),
            cv2.USAC_MAGSAC,
            config.ransac_threshold_px,
            maxIters=config.max_iters,
            confidence=config.confidence,
        )
    except cv2.error as err:
        logger.debug("findHomography failed: %s", err)
        return _failure(Reason.ESTIMATION_FAILED, n)
    if h is None or mask is None:
        return _failure(Reason.ESTIMATION_FAILED, n)
    inliers = np.zeros(n, dtype=bool)
    inliers[np.flatnonzero(finite)] = mask.reshape(-1).astype(bool)
    if inliers.sum() < config.min_inliers:
        return _failure(Reason.TOO_FEW_INLIERS, n, inliers)
    if _degenerate_points(kpts_render[inliers]):
        return _failure(Reason.DEGENERATE_MATCHES, n, inliers)
    h = np.asarray(h, dtype=np.float64)
    if not np.all(np.isfinite(h)) or abs(h[2, 2]) < 1e-12:
        return _failure(Reason.NON_FINITE, n, inliers)
    h = h / h[2, 2]
    reason = check_homography(h, width, height, config)
    if reason is not None:
        return _failure(reason, n, inliers)
    return HomographyResult(True, None, h, inliers)


def scale_homography(h: np.ndarray, scale_x: float, scale_y: float) -> np.ndarray:
    """Express a homography fitted on resized images in original pixels.

    The working images are the originals resized by (scale_x, scale_y), with pixel centres
    mapping as ``x_work = (x + 0.5) * s - 0.5``. Returns ``S^-1 @ h @ S``.
    """
    s = np.array([[scale_x, 0, 0.5 * scale_x - 0.5], [0, scale_y, 0.5 * scale_y - 0.5], [0, 0, 1.0]])
    return np.linalg.inv(s) @ np.asarray(h, dtype=np.float64) @ s


def corner_displacements(h: np.ndarray, width: float, height: float) -> np.ndarray:
    """(4, 2) displacement of each image corner under ``h`` (warped - original), in pixels."""
    corners = image_corners(width, height)
    return apply_homography(h, corners) - corners


def corner_error(h: np.ndarray, width: float, height: float) -> float:
    """Mean distance (px) between the image corners warped by ``h`` and the unwarped corners.

    0 for the identity. ``inf`` if a corner maps to infinity.
    """
    d = corner_displacements(h, width, height)
    if not np.all(np.isfinite(d)):
        return float("inf")
    return float(np.mean(np.linalg.norm(d, axis=1)))


def corner_shift_and_zoom(h: np.ndarray, width: float, height: float) -> tuple[float, float, float]:
    """Summarise a near-identity homography as (dx, dy, zoom).

    dx, dy: mean corner displacement (px); zoom: ratio of warped to original diagonal lengths.
    Used to spot systematic offsets (a constant shift or zoom across frames points at
    calibration, not at single poses).
    """
    corners = image_corners(width, height)
    warped = apply_homography(h, corners)
    d = warped - corners
    diag0 = np.linalg.norm(corners[2] - corners[0]) + np.linalg.norm(corners[3] - corners[1])
    diag1 = np.linalg.norm(warped[2] - warped[0]) + np.linalg.norm(warped[3] - warped[1])
    return float(d[:, 0].mean()), float(d[:, 1].mean()), float(diag1 / diag0)


def auc_at_thresholds(errors: np.ndarray, thresholds: tuple[float, ...] = (1.0, 3.0, 5.0)) -> dict[str, float]:
    """Area under the recall-vs-error curve up to each threshold (glue-factory style).

    errors: (N,) corner errors in px; failures must be passed as ``inf`` so they stay in the
    denominator. Returns {"auc@1px": ..., ...} in [0, 1]; empty input gives 0.
    """
    errors = np.sort(np.asarray(errors, dtype=np.float64).reshape(-1))
    out: dict[str, float] = {}
    n = len(errors)
    for t in thresholds:
        key = f"auc@{t:g}px"
        if n == 0:
            out[key] = 0.0
            continue
        recall = (np.arange(n) + 1) / n
        e = np.concatenate([[0.0], errors])
        r = np.concatenate([[0.0], recall])
        last = int(np.searchsorted(e, t))
        xs = np.concatenate([e[:last], [t]])
        ys = np.concatenate([r[:last], [r[last - 1]]])
        # trapezoid rule written out: np.trapezoid needs NumPy >= 2, np.trapz is gone in 2.x
        area = 0.5 * np.sum(np.diff(xs) * (ys[1:] + ys[:-1]))
        out[key] = float(area / t)
    return out
