"""Per-frame image assets of the HTML report: which frames get them, and writing them.

The measurement stage does not keep images. During the main pass a ``PanelWriter`` (given to
each worker's ``FrameChecker`` as its ``panel_sink``) writes the panels of the frames that are
likely to be shown (no measurement, few inliers, corner error near or above the threshold, and
the worst PASS frames seen so far) and a small manifest per frame; after the verdicts the runner
takes the panels of the selected frames (``select_detail_frames``) from those manifests
(``main_pass_assets``) and measures again only the frames still missing
(``FrameChecker.measure(frame, keep=FrameImages())``). Panels are JPEG files at working
resolution (long side <= ``PANEL_MAX``) under ``OUT/assets/frames/`` with generated names (a hash
of the frame id, never the user's file name); their index is ``OUT/assets/index.json`` so
``pgt-check report`` can rebuild the HTML without recomputing.
"""

from __future__ import annotations

import hashlib
import heapq
import json
import logging
import math
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from pgt_check.config import VerdictConfig
    from pgt_check.measure.paths import FrameImages, PathImages
    from pgt_check.measure.record import FrameMeasurement

logger = logging.getLogger(__name__)

ASSETS_DIR = "assets"
FRAMES_SUBDIR = "frames"
INDEX_NAME = "index.json"
MANIFEST_VERSION = 1
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
#: asset kinds in display order
ASSET_KINDS = (
    "render", "enhanced", "photo", "diff", "blend", "checker", "arrows_raw", "arrows_enhanced",
)

_INLIER_BGR = (60, 200, 60)
_OUTLIER_BGR = (40, 40, 230)
#: homography arrows per path (BGR): raw orange, enhanced cyan-blue
PATH_BGR = {"raw": (0, 140, 255), "enhanced": (255, 200, 0)}


def _error_key(rec: Mapping[str, Any]) -> float:
    err = rec.get("corner_error_px")
    if err is None or not isinstance(err, (int, float)) or not math.isfinite(err):
        return math.inf
    return float(err)


def select_detail_frames(
    records: Sequence[Mapping[str, Any]], n_worst: int = 20, max_details: int = 200
) -> list[str]:
    """Frame ids that get detail assets, most important first.

    All FAIL frames (largest corner error first), then all UNVERIFIABLE frames (in input order),
    up to ``max_details``; then up to ``n_worst`` PASS frames with the largest corner error, still
    within ``max_details``. Records need ``frame_id``, ``verdict`` and ``corner_error_px``.
    """
    if max_details <= 0:
        return []
    fails = [r for r in records if r.get("verdict") == "FAIL"]
    fails.sort(key=_error_key, reverse=True)
    unver = [r for r in records if r.get("verdict") == "UNVERIFIABLE"]
    passes = [r for r in records if r.get("verdict") == "PASS"]
    passes.sort(key=_error_key, reverse=True)
    out: list[str] = []
    for r in fails + unver:
        if len(out) >= max_details:
            return out
        out.append(r["frame_id"])
    for r in passes[: max(0, n_worst)]:
        if len(out) >= max_details:
            break
        out.append(r["frame_id"])
    return out


def asset_stem(frame_id: Any) -> str:
    """A safe file-name stem for a frame: a hash of its id (never the user's file name)."""
    return hashlib.sha256(str(frame_id).encode("utf-8")).hexdigest()[:20]


def _to_uint8_bgr(image: np.ndarray) -> np.ndarray:
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


def _resize(image: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    from pgt_check.io.images import resize_image

    return resize_image(image, size)


def _fit(img: np.ndarray, max_side: int) -> np.ndarray:
    h, w = img.shape[:2]
    s = _panel_scale(w, h, max_side)
    if s >= 1.0:
        return img
    return _resize(img, (max(1, round(w * s)), max(1, round(h * s))))


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
    r, p = _fit(render, max_side), _fit(photo, max_side)
    if r.shape != p.shape:
        r = _resize(r, (p.shape[1], p.shape[0]))
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
    import cv2

    canvas = (photo.astype(np.float32) * 0.55 + 40).astype(np.uint8)
    k = int(max(1, magnification))
    k0 = np.asarray(path.kpts_render, np.float64).reshape(-1, 2)
    k1 = np.asarray(path.kpts_photo, np.float64).reshape(-1, 2)
    n = min(len(k0), len(k1))
    inl = np.zeros(n, bool)
    if path.inliers is not None:
        given = np.asarray(path.inliers, bool).reshape(-1)[:n]
        inl[: len(given)] = given
    rng = np.random.default_rng(seed)
    idx_in, idx_out = np.flatnonzero(inl), np.flatnonzero(~inl)
    n_out = min(len(idx_out), max_drawn // 4)
    n_in = min(len(idx_in), max_drawn - n_out)
    if len(idx_in) > n_in:
        idx_in = rng.choice(idx_in, n_in, replace=False)
    if len(idx_out) > n_out:
        idx_out = rng.choice(idx_out, n_out, replace=False)
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
    colour = PATH_BGR.get(name, (255, 255, 255))
    h, w = canvas.shape[:2]
    thick = max(2, round(max(h, w) / 400))
    if path.photo_from_render is not None:
        pts = grid_points(w, h)
        d = homography_displacements(path.photo_from_render, pts)
        for p, dp in zip(pts, d, strict=True):
            if not np.all(np.isfinite(dp)):
                continue
            q = p + k * dp
            cv2.arrowedLine(canvas, (round(p[0]), round(p[1])), (round(q[0]), round(q[1])),
                            colour, thick, cv2.LINE_AA, tipLength=0.25)
        text = f"{name.upper()}: arrows x{k} (homography), {int(inl.sum())}/{n} inliers"
    else:
        text = f"{name.upper()}: no homography, {n} matches"
    _label(canvas, text, colour)
    return canvas


def _write_jpeg(path: Path, bgr: np.ndarray, quality: int = JPEG_QUALITY) -> None:
    import cv2

    path.parent.mkdir(parents=True, exist_ok=True)
    ok, buf = cv2.imencode(".jpg", bgr, [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
    if not ok:  # pragma: no cover - encoding a valid uint8 image does not fail
        raise ValueError(f"could not encode {path.name}")
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_bytes(buf.tobytes())
    tmp.replace(path)


def _scaled_path(path: PathImages, s: float) -> PathImages:
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


def _frame_paths(images: FrameImages) -> dict[str, PathImages]:
    """The per-path matches; images filled by an older checker only have the deciding path."""
    paths = dict(getattr(images, "paths", None) or {})
    if not paths and images.kpts_render is not None and images.kpts_photo is not None:
        from pgt_check.measure.paths import PathImages

        inl = images.inliers if images.inliers is not None else np.zeros(len(images.kpts_render),
                                                                           bool)
        paths["enhanced" if images.enhanced is not None else "raw"] = PathImages(
            images.kpts_render, images.kpts_photo, inl, None)
    return paths


def write_frame_assets(
    out_dir: str | Path, record: Mapping[str, Any], images: FrameImages
) -> dict[str, str]:
    """Write the JPEG panels of one frame; return ``{kind: path relative to out_dir}``.

    Kinds (each only when its inputs exist): ``render``, ``enhanced``, ``photo``, ``diff``
    (render | photo | difference), ``blend`` (50 % render + photo), ``checker`` (checkerboard of
    render and photo), ``arrows_raw`` / ``arrows_enhanced`` (the photo with that path's matches
    and its homography applied to a grid, as arrows magnified by one factor per frame). Panels
    keep the working resolution up to a long side of ``PANEL_MAX``. File names are a hash of the
    frame id plus the kind.
    """
    out_dir = Path(out_dir)
    stem = asset_stem(record["frame_id"])
    rel_dir = f"{ASSETS_DIR}/{FRAMES_SUBDIR}"
    written: dict[str, str] = {}

    def put(kind: str, bgr: np.ndarray) -> None:
        rel = f"{rel_dir}/{stem}_{kind}.jpg"
        _write_jpeg(out_dir / rel, bgr)
        written[kind] = rel

    panels: dict[str, np.ndarray] = {}
    for kind in ("render", "enhanced", "photo"):
        img = getattr(images, kind, None)
        if img is None:
            continue
        panels[kind] = _fit(_to_uint8_bgr(img), PANEL_MAX)
        put(kind, panels[kind])
    if "render" in panels and "photo" in panels:
        render, photo = panels["render"], panels["photo"]
        if render.shape != photo.shape:
            render = _resize(render, (photo.shape[1], photo.shape[0]))
        put("diff", diff_tile(render, photo))
        blend = (render.astype(np.uint16) + photo.astype(np.uint16) + 1) // 2
        put("blend", blend.astype(np.uint8))
        put("checker", checkerboard(render, photo))
    if "photo" in panels:
        photo = panels["photo"]
        s = photo.shape[1] / np.asarray(images.photo).shape[1]
        paths = {k: _scaled_path(v, s) for k, v in _frame_paths(images).items()}
        disp = []
        for p in paths.values():
            if p.photo_from_render is not None:
                pts = grid_points(photo.shape[1], photo.shape[0])
                disp.append(homography_displacements(p.photo_from_render, pts))
        mag = arrow_magnification(disp)
        for name in ("raw", "enhanced"):
            if name in paths:
                put(f"arrows_{name}", draw_arrows(photo, paths[name], name, mag))
    logger.debug("frame %s: wrote %d report assets", record["frame_id"], len(written))
    return written


# -- panels during the main pass ------------------------------------------------------------------
def manifest_path(out_dir: str | Path, frame_id: Any) -> Path:
    return Path(out_dir) / ASSETS_DIR / FRAMES_SUBDIR / f"{asset_stem(frame_id)}.json"


class PanelWriter:
    """A ``FrameChecker.panel_sink``: writes the panels of frames likely to be shown in the
    report while they are measured, so the report does not measure them again.

    A frame gets panels when it has no measurement or no homography, fewer inliers than the
    verdict needs, a corner error of at least ``near`` times its threshold, or one of the
    ``n_worst`` largest errors this writer has seen so far (so the worst PASS frames of the run
    are always among them: at most about ``n_worst * ln(frames / n_worst)`` extra frames per
    worker). Each frame's panels are followed by a manifest (``<hash>.json``) with the
    measurement fingerprint; ``main_pass_assets`` reads them back. Picklable: every worker gets
    its own copy.
    """

    def __init__(
        self, out_dir: str | Path, fingerprint: str, verdict: VerdictConfig,
        near: float = 0.5, n_worst: int = 20,
    ) -> None:
        self.out_dir = str(out_dir)
        self.fingerprint = fingerprint
        self.verdict = verdict
        self.near = near
        self.n_worst = n_worst
        self._worst: list[float] = []  # min-heap of the largest errors seen
        self.n_written = 0

    def wants(self, m: FrameMeasurement) -> bool:
        """Whether ``m`` is likely a detail frame (updates the running worst-errors list)."""
        chosen = m.chosen
        if m.error.value or chosen is None or not chosen.success:
            return True
        err = chosen.corner_error_px
        if err is None or not math.isfinite(err):
            return True
        if chosen.n_inliers < getattr(self.verdict, "min_inliers", 0):
            return True
        if err >= self.near * self.verdict.threshold_for(m.width, m.height):
            return True
        if self.n_worst <= 0:
            return False
        if len(self._worst) < self.n_worst:
            heapq.heappush(self._worst, err)
            return True
        if err > self._worst[0]:
            heapq.heapreplace(self._worst, err)
            return True
        return False

    def __call__(self, m: FrameMeasurement, images: FrameImages | None) -> dict[str, str] | None:
        if images is None or images.photo is None or not self.wants(m):
            return None
        from pgt_check.report.files import atomic_write_text

        kinds = write_frame_assets(self.out_dir, {"frame_id": m.frame_id}, images)
        manifest = {"version": MANIFEST_VERSION, "frame_id": m.frame_id,
                    "fingerprint": self.fingerprint, "kinds": kinds}
        atomic_write_text(manifest_path(self.out_dir, m.frame_id), json.dumps(manifest) + "\n")
        self.n_written += 1
        return kinds


def main_pass_assets(
    out_dir: str | Path, frame_ids: Iterable[str], fingerprint: str
) -> dict[str, dict[str, str]]:
    """Panels written during the main pass for ``frame_ids`` (same measurement fingerprint,
    every file present); frames without them are left out."""
    out: dict[str, dict[str, str]] = {}
    for fid in frame_ids:
        path = manifest_path(out_dir, fid)
        try:
            data = json.loads(path.read_text(encoding="utf-8"))
        except (OSError, ValueError):
            continue
        if (
            not isinstance(data, dict)
            or data.get("fingerprint") != fingerprint
            or data.get("frame_id") != fid
            or not isinstance(data.get("kinds"), dict)
        ):
            continue
        kinds = existing_assets(out_dir, {fid: data["kinds"]}, warn=False).get(fid, {})
        if kinds and len(kinds) == len(data["kinds"]):
            out[fid] = kinds
    return out


def prune_panels(out_dir: str | Path, keep_ids: Iterable[str]) -> int:
    """Delete the panels and manifests of frames not in ``keep_ids`` (written during the main
    pass for frames that were not selected in the end). Returns the number of files removed."""
    folder = Path(out_dir) / ASSETS_DIR / FRAMES_SUBDIR
    if not folder.is_dir():
        return 0
    keep = {asset_stem(f) for f in keep_ids}
    removed = 0
    for path in folder.iterdir():
        stem = path.name.split("_", 1)[0].split(".", 1)[0]
        if len(stem) == 20 and stem not in keep and path.suffix in (".jpg", ".json"):
            path.unlink(missing_ok=True)
            removed += 1
    return removed

def index_path(out_dir: str | Path) -> Path:
    return Path(out_dir) / ASSETS_DIR / INDEX_NAME


def write_assets_index(out_dir: str | Path, assets: Mapping[str, Mapping[str, str]]) -> None:
    """Store ``{frame_id: {kind: relative path}}`` as ``assets/index.json``."""
    from pgt_check.report.files import atomic_write_text

    path = index_path(out_dir)
    path.parent.mkdir(parents=True, exist_ok=True)
    data = {"version": 1, "frames": {str(k): dict(v) for k, v in assets.items()}}
    atomic_write_text(path, json.dumps(data, indent=1, sort_keys=True) + "\n")


def _safe_relative(rel: str) -> bool:
    p = Path(rel)
    return (
        not p.is_absolute()
        and ".." not in p.parts
        and bool(p.parts)
        and p.parts[0] == ASSETS_DIR
        and "\\" not in rel
    )


def load_assets_index(out_dir: str | Path) -> dict[str, dict[str, str]]:
    """Read ``assets/index.json``; {} when absent. Entries whose files are gone are dropped."""
    path = index_path(out_dir)
    if not path.is_file():
        return {}
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, json.JSONDecodeError) as err:
        logger.warning("ignoring unreadable %s: %s", path, err)
        return {}
    frames = data.get("frames", {}) if isinstance(data, dict) else {}
    return existing_assets(out_dir, frames)


def existing_assets(
    out_dir: str | Path, assets: Mapping[str, Mapping[str, str]] | None, warn: bool = True
) -> dict[str, dict[str, str]]:
    """Only the asset entries that are safe relative paths to existing files under ``out_dir``."""
    out_dir = Path(out_dir)
    out: dict[str, dict[str, str]] = {}
    missing = 0
    for fid, kinds in (assets or {}).items():
        if not isinstance(kinds, Mapping):
            continue
        keep = {}
        for kind, rel in kinds.items():
            if isinstance(rel, str) and _safe_relative(rel) and (out_dir / rel).is_file():
                keep[str(kind)] = rel
            else:
                missing += 1
        if keep:
            out[str(fid)] = keep
    if missing and warn:
        logger.warning("%d report assets are missing or unsafe and are not shown", missing)
    return out
