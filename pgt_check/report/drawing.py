"""Drawing of the report's per-frame panels (pure image functions on uint8 BGR arrays):
resizing, the render | photo | difference tile, checkerboard, homography arrows with the
matches of a path, and JPEG writing. ``pgt_check.report.assets`` decides which frames get
panels and where they are written.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from pgt_check.measure.paths import FrameImages, PathImages


#: longest side of a panel, px (panels are shown small and open full size on click)
PANEL_MAX = 1280
#: longest side of each of the three tiles of the render | photo | difference panel
TILE_MAX = 640
JPEG_QUALITY = 85
#: most match vectors drawn per path (inliers and outliers together)
MAX_DRAWN_MATCHES = 300
#: homography arrows: grid points along x and y
ARROW_GRID = (9, 7)
#: median arrow length the magnification aims at, in panel pixels
ARROW_TARGET_PX = 30.0
MAX_MAGNIFICATION = 20

_INLIER_BGR = (60, 200, 60)
_OUTLIER_BGR = (40, 40, 230)
#: homography arrows per path (BGR): raw orange, enhanced cyan-blue
PATH_BGR = {"raw": (0, 140, 255), "enhanced": (255, 200, 0)}


def to_uint8_bgr(image: np.ndarray) -> np.ndarray:
    """(h, w, 3) RGB float [0, 1] (or uint8, or (h, w) grey) -> (h, w, 3) uint8 BGR."""
    img = np.asarray(image)
    if img.ndim == 2:
        img = np.repeat(img[:, :, None], 3, axis=2)
    if img.ndim != 3 or img.shape[2] < 3:
        raise ValueError(f"expected an (h, w, 3) image, got shape {img.shape}")
    img = img[:, :, :3]
    if img.dtype != np.uint8:
        img = np.clip(np.nan_to_num(img.astype(np.float32)) * 255.0 + 0.5, 0, 255).astype(np.uint8)
    return np.ascontiguousarray(img[:, :, ::-1])


def _panel_scale(width: int, height: int, max_side: int = PANEL_MAX) -> float:
    return min(1.0, max_side / max(width, height, 1))


def resize(image: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    from pgt_check.io.images import resize_image

    return resize_image(image, size)


def fit(img: np.ndarray, max_side: int) -> np.ndarray:
    h, w = img.shape[:2]
    s = _panel_scale(w, h, max_side)
    if s >= 1.0:
        return img
    return resize(img, (max(1, round(w * s)), max(1, round(h * s))))


def checkerboard(a: np.ndarray, b: np.ndarray, n_tiles: int = 8) -> np.ndarray:
    """Alternate square tiles of ``a`` and ``b`` (same shape): edges that do not line up show a
    misalignment. ``n_tiles`` tiles along the longer side."""
    h, w = a.shape[:2]
    tile = max(1, math.ceil(max(h, w) / n_tiles))
    yy, xx = np.mgrid[0:h, 0:w]
    mask = ((yy // tile + xx // tile) % 2).astype(bool)
    out = a.copy()
    out[mask] = b[mask]
    return out


def difference_image(render: np.ndarray, photo: np.ndarray, gain: float = 2.0) -> np.ndarray:
    """|render - photo| of the grey levels, times ``gain``, as uint8 BGR (white = different).

    render/photo: (h, w, 3) uint8 of the same shape. Each image is first normalised to zero mean
    and unit spread of its grey level, so an overall brightness change does not show."""
    if render.shape != photo.shape:
        raise ValueError(f"render {render.shape} and photo {photo.shape} differ in shape")

    def grey(img: np.ndarray) -> np.ndarray:
        g = img.astype(np.float32).mean(axis=2)
        return (g - g.mean()) / max(float(g.std()), 1e-3)

    d = np.abs(grey(render) - grey(photo)) * (255.0 * gain / 6.0)
    d = np.clip(d + 0.5, 0, 255).astype(np.uint8)
    return np.repeat(d[:, :, None], 3, axis=2)


def _label(img: np.ndarray, text: str, colour: tuple[int, int, int] = (255, 255, 255)) -> None:
    """Draw ``text`` in the top-left corner on a dark box (in place)."""
    import cv2

    scale = max(0.4, min(img.shape[1] / 900.0, 1.0))
    (tw, th), base = cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, scale, 1)
    cv2.rectangle(img, (0, 0), (tw + 8, th + base + 8), (30, 30, 30), -1)
    cv2.putText(img, text, (4, th + 4), cv2.FONT_HERSHEY_SIMPLEX, scale, colour, 1, cv2.LINE_AA)


def diff_tile(render: np.ndarray, photo: np.ndarray, max_side: int = TILE_MAX) -> np.ndarray:
    """One image: render | photo | difference (uint8 BGR, each tile long side <= max_side)."""
    r, p = fit(render, max_side), fit(photo, max_side)
    if r.shape != p.shape:
        r = resize(r, (p.shape[1], p.shape[0]))
    tiles = [r.copy(), p.copy(), difference_image(r, p)]
    for tile, text in zip(tiles, ("render", "photo", "|difference|"), strict=True):
        _label(tile, text)
    gap = np.full((p.shape[0], 4, 3), 255, np.uint8)
    return np.concatenate([tiles[0], gap, tiles[1], gap, tiles[2]], axis=1)


def grid_points(width: int, height: int, n: tuple[int, int] = ARROW_GRID) -> np.ndarray:
    """(nx * ny, 2) points of a regular grid inside the image (margins of half a cell)."""
    xs = (np.arange(n[0]) + 0.5) * width / n[0] - 0.5
    ys = (np.arange(n[1]) + 0.5) * height / n[1] - 0.5
    xx, yy = np.meshgrid(xs, ys)
    return np.stack([xx.ravel(), yy.ravel()], axis=1)


def homography_displacements(h: np.ndarray, points: np.ndarray) -> np.ndarray:
    """(N, 2) displacement ``H p - p`` of each point (NaN where H sends it to infinity)."""
    p = np.asarray(points, np.float64).reshape(-1, 2)
    ph = np.concatenate([p, np.ones((len(p), 1))], axis=1) @ np.asarray(h, np.float64).T
    with np.errstate(divide="ignore", invalid="ignore"):
        q = ph[:, :2] / ph[:, 2:3]
    d = q - p
    d[~np.all(np.isfinite(d), axis=1)] = np.nan
    return d


def arrow_magnification(displacements: Iterable[np.ndarray]) -> int:
    """One integer factor for all arrows of a frame: the median arrow becomes about
    ``ARROW_TARGET_PX`` long; between 1 and ``MAX_MAGNIFICATION``."""
    lengths = [np.linalg.norm(d, axis=1) for d in displacements if d is not None and len(d)]
    vals = np.concatenate(lengths) if lengths else np.zeros(0)
    vals = vals[np.isfinite(vals)]
    med = float(np.median(vals)) if len(vals) else 0.0
    if med <= 1e-6:
        return MAX_MAGNIFICATION
    return int(np.clip(round(ARROW_TARGET_PX / med), 1, MAX_MAGNIFICATION))


def draw_arrows(
    photo: np.ndarray,
    path: PathImages,
    name: str,
    magnification: int,
    max_drawn: int = MAX_DRAWN_MATCHES,
    seed: int = 0,
) -> np.ndarray:
    """The photo (dimmed) with one path's matches and its homography as displacement arrows.

    photo: (h, w, 3) uint8 BGR at working resolution (the pixels of ``path``). Each match is
    drawn where it lies in the render, with a thin line towards where the photo has it (inliers
    green, outliers red dots); the homography moves a grid of points (thick arrows in the path's
    colour). Lines and arrows are ``magnification`` times their length (written on the panel).
    """
    canvas = (photo.astype(np.float32) * 0.55 + 40).astype(np.uint8)
    k = int(max(1, magnification))
    k0, k1, inl = _matches(path)
    n = len(inl)
    idx_in, idx_out = _drawn_matches(inl, max_drawn, seed)
    _draw_matches(canvas, k0, k1, idx_in, idx_out, k)
    colour = PATH_BGR.get(name, (255, 255, 255))
    if path.photo_from_render is not None:
        _draw_homography_arrows(canvas, path.photo_from_render, k, colour)
        text = f"{name.upper()}: arrows x{k} (homography), {int(inl.sum())}/{n} inliers"
    else:
        text = f"{name.upper()}: no homography, {n} matches"
    _label(canvas, text, colour)
    return canvas


def _matches(path: PathImages) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(N, 2) render and (N', 2) photo keypoints of a path and the (n,) inlier mask of its
    n = min(N, N') matches (all False where the path gives none)."""
    k0 = np.asarray(path.kpts_render, np.float64).reshape(-1, 2)
    k1 = np.asarray(path.kpts_photo, np.float64).reshape(-1, 2)
    n = min(len(k0), len(k1))
    inl = np.zeros(n, bool)
    if path.inliers is not None:
        given = np.asarray(path.inliers, bool).reshape(-1)[:n]
        inl[: len(given)] = given
    return k0, k1, inl


def _drawn_matches(inl: np.ndarray, max_drawn: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Indices of the inliers and outliers to draw: at most ``max_drawn`` in all, outliers at
    most a quarter, a seeded random sample where there are more."""
    rng = np.random.default_rng(seed)
    idx_in, idx_out = np.flatnonzero(inl), np.flatnonzero(~inl)
    n_out = min(len(idx_out), max_drawn // 4)
    n_in = min(len(idx_in), max_drawn - n_out)
    if len(idx_in) > n_in:
        idx_in = rng.choice(idx_in, n_in, replace=False)
    if len(idx_out) > n_out:
        idx_out = rng.choice(idx_out, n_out, replace=False)
    return idx_in, idx_out


def _draw_matches(
    canvas: np.ndarray,
    k0: np.ndarray,
    k1: np.ndarray,
    idx_in: np.ndarray,
    idx_out: np.ndarray,
    k: int,
) -> None:
    """Draw outliers as red dots and inliers as green lines ``k`` times their length, in place
    on ``canvas``; returns None."""
    import cv2

    for i in idx_out:
        if np.all(np.isfinite(k0[i])):
            cv2.circle(canvas, (round(k0[i][0]), round(k0[i][1])), 2, _OUTLIER_BGR, -1, cv2.LINE_AA)
    for i in idx_in:
        a, b = k0[i], k0[i] + k * (k1[i] - k0[i])
        if not (np.all(np.isfinite(a)) and np.all(np.isfinite(b))):
            continue
        pa, pb = (round(a[0]), round(a[1])), (round(b[0]), round(b[1]))
        cv2.line(canvas, pa, pb, _INLIER_BGR, 1, cv2.LINE_AA)
        cv2.circle(canvas, pa, 2, _INLIER_BGR, -1, cv2.LINE_AA)


def _draw_homography_arrows(
    canvas: np.ndarray, photo_from_render: np.ndarray, k: int, colour: tuple[int, int, int]
) -> None:
    """Draw the (3, 3) homography's displacement of a point grid as arrows ``k`` times their
    length, in place on ``canvas``; returns None."""
    import cv2

    h, w = canvas.shape[:2]
    thick = max(2, round(max(h, w) / 400))
    pts = grid_points(w, h)
    d = homography_displacements(photo_from_render, pts)
    for p, dp in zip(pts, d, strict=True):
        if not np.all(np.isfinite(dp)):
            continue
        q = p + k * dp
        cv2.arrowedLine(canvas, (round(p[0]), round(p[1])), (round(q[0]), round(q[1])),
                        colour, thick, cv2.LINE_AA, tipLength=0.25)


def write_jpeg(path: Path, bgr: np.ndarray, quality: int = JPEG_QUALITY) -> None:
    import cv2

    path.parent.mkdir(parents=True, exist_ok=True)
    ok, buf = cv2.imencode(".jpg", bgr, [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
    if not ok:  # pragma: no cover - encoding a valid uint8 image does not fail
        raise ValueError(f"could not encode {path.name}")
    from pgt_check.common.files import atomic_write_bytes

    atomic_write_bytes(path, buf.tobytes())


def scaled_path(path: PathImages, s: float) -> PathImages:
    """A path's matches in the pixels of an image resized by ``s`` (pixel centres kept)."""
    from dataclasses import replace

    def pts(k):
        return None if k is None else (np.asarray(k, np.float64) + 0.5) * s - 0.5

    h = path.photo_from_render
    if h is not None and s != 1.0:
        m = np.array([[s, 0, 0.5 * s - 0.5], [0, s, 0.5 * s - 0.5], [0, 0, 1.0]])
        h = m @ np.asarray(h, np.float64) @ np.linalg.inv(m)
    return replace(path, kpts_render=pts(path.kpts_render), kpts_photo=pts(path.kpts_photo),
                   photo_from_render=h)


def frame_paths(images: FrameImages) -> dict[str, PathImages]:
    """The per-path matches; images filled by an older checker only have the deciding path."""
    paths = dict(getattr(images, "paths", None) or {})
    if not paths and images.kpts_render is not None and images.kpts_photo is not None:
        from pgt_check.measure.paths import PathImages

        inl = images.inliers if images.inliers is not None else np.zeros(len(images.kpts_render),
                                                                           bool)
        paths["enhanced" if images.enhanced is not None else "raw"] = PathImages(
            images.kpts_render, images.kpts_photo, inl, None)
    return paths
