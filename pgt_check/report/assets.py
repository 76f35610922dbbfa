"""Per-frame image assets of the HTML report: which frames get them, and writing them.

The measurement stage does not keep images. After verdicts, the runner picks a bounded set of
frames (``select_detail_frames``), re-measures only those with ``FrameChecker.measure(frame,
keep=FrameImages())`` and hands the kept images to ``write_frame_assets``. The assets are JPEG
thumbnails under ``OUT/assets/frames/`` with generated names (a hash of the frame id, never the
user's file name); their index is ``OUT/assets/index.json`` so ``pgt-check report`` can rebuild
the HTML without recomputing.
"""

from __future__ import annotations

import hashlib
import json
import logging
import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from pgt_check.measure.checker import FrameImages

logger = logging.getLogger(__name__)

ASSETS_DIR = "assets"
FRAMES_SUBDIR = "frames"
INDEX_NAME = "index.json"
#: longest side of a thumbnail, px
THUMB_MAX = 480
JPEG_QUALITY = 85
#: most match lines drawn per frame (inliers and outliers together)
MAX_DRAWN_MATCHES = 200
#: asset kinds in display order
ASSET_KINDS = ("render", "enhanced", "photo", "blend", "checker", "matches")

_INLIER_BGR = (60, 200, 60)
_OUTLIER_BGR = (40, 40, 230)


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


def _thumb_scale(width: int, height: int, max_side: int = THUMB_MAX) -> float:
    return min(1.0, max_side / max(width, height, 1))


def _resize(image: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    from pgt_check.io.images import resize_image

    return resize_image(image, size)


def _thumb(img: np.ndarray, max_side: int = THUMB_MAX) -> np.ndarray:
    h, w = img.shape[:2]
    s = _thumb_scale(w, h, max_side)
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


def draw_matches(
    left: np.ndarray,
    right: np.ndarray,
    kpts_left: np.ndarray | None,
    kpts_right: np.ndarray | None,
    inliers: np.ndarray | None,
    max_drawn: int = MAX_DRAWN_MATCHES,
    seed: int = 0,
) -> np.ndarray:
    """Side-by-side uint8 BGR images with match lines: inliers green, outliers red.

    left/right: (h, w, 3) uint8 BGR of the same height (the thumbnails); kpts_*: (N, 2) in the
    pixel frame of ``left``/``right``; inliers: (N,) bool or None (all drawn as outliers). At most
    ``max_drawn`` lines, inliers first (a fixed-seed random subset when there are more).
    """
    import cv2

    h = max(left.shape[0], right.shape[0])
    canvas = np.zeros((h, left.shape[1] + right.shape[1], 3), np.uint8)
    canvas[: left.shape[0], : left.shape[1]] = left
    canvas[: right.shape[0], left.shape[1] :] = right
    if kpts_left is None or kpts_right is None or len(kpts_left) == 0:
        return canvas
    k0 = np.asarray(kpts_left, np.float64).reshape(-1, 2)
    k1 = np.asarray(kpts_right, np.float64).reshape(-1, 2)
    n = min(len(k0), len(k1))
    inl = np.zeros(n, bool) if inliers is None else np.asarray(inliers, bool).reshape(-1)[:n]
    if len(inl) < n:
        inl = np.concatenate([inl, np.zeros(n - len(inl), bool)])
    rng = np.random.default_rng(seed)
    idx_in = np.flatnonzero(inl)
    idx_out = np.flatnonzero(~inl)
    n_in = min(len(idx_in), max(max_drawn - min(len(idx_out), max_drawn // 4), 0))
    n_out = min(len(idx_out), max_drawn - n_in)
    if len(idx_in) > n_in:
        idx_in = rng.choice(idx_in, n_in, replace=False)
    if len(idx_out) > n_out:
        idx_out = rng.choice(idx_out, n_out, replace=False)
    off = left.shape[1]
    for idx, colour in ((idx_out, _OUTLIER_BGR), (idx_in, _INLIER_BGR)):
        for i in idx:
            p0 = k0[i]
            p1 = k1[i]
            if not (np.all(np.isfinite(p0)) and np.all(np.isfinite(p1))):
                continue
            a = (round(p0[0]), round(p0[1]))
            b = (round(p1[0]) + off, round(p1[1]))
            cv2.line(canvas, a, b, colour, 1, cv2.LINE_AA)
            cv2.circle(canvas, a, 2, colour, -1, cv2.LINE_AA)
            cv2.circle(canvas, b, 2, colour, -1, cv2.LINE_AA)
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


def write_frame_assets(
    out_dir: str | Path, record: Mapping[str, Any], images: FrameImages
) -> dict[str, str]:
    """Write the JPEG thumbnails of one frame; return ``{kind: path relative to out_dir}``.

    Kinds (each only when its inputs exist): ``render``, ``enhanced``, ``photo``, ``blend`` (50 %
    render + photo), ``checker`` (checkerboard of render and photo), ``matches`` (render | photo
    with the matches: inliers green, outliers red). Thumbnails have a long side <= 480 px. File
    names are a hash of the frame id plus the kind.
    """
    out_dir = Path(out_dir)
    stem = asset_stem(record["frame_id"])
    rel_dir = f"{ASSETS_DIR}/{FRAMES_SUBDIR}"
    written: dict[str, str] = {}

    def put(kind: str, bgr: np.ndarray) -> None:
        rel = f"{rel_dir}/{stem}_{kind}.jpg"
        _write_jpeg(out_dir / rel, bgr)
        written[kind] = rel

    thumbs: dict[str, np.ndarray] = {}
    scale: dict[str, float] = {}
    for kind in ("render", "enhanced", "photo"):
        img = getattr(images, kind, None)
        if img is None:
            continue
        bgr = _to_uint8_bgr(img)
        scale[kind] = _thumb_scale(bgr.shape[1], bgr.shape[0])
        thumbs[kind] = _thumb(bgr)
        put(kind, thumbs[kind])
    if "render" in thumbs and "photo" in thumbs:
        render, photo = thumbs["render"], thumbs["photo"]
        if render.shape != photo.shape:
            render = _resize(render, (photo.shape[1], photo.shape[0]))
        blend = (render.astype(np.uint16) + photo.astype(np.uint16) + 1) // 2
        put("blend", blend.astype(np.uint8))
        put("checker", checkerboard(render, photo))
        left = thumbs.get("enhanced", thumbs["render"])
        s_left = scale.get("enhanced", scale["render"])
        if left.shape[0] != photo.shape[0]:
            s_fix = photo.shape[0] / left.shape[0]
            left = _resize(left, (max(1, round(left.shape[1] * s_fix)), photo.shape[0]))
            s_left *= s_fix
        k0 = (
            None
            if images.kpts_render is None
            else (np.asarray(images.kpts_render) + 0.5) * s_left - 0.5
        )
        k1 = (
            None
            if images.kpts_photo is None
            else (np.asarray(images.kpts_photo) + 0.5) * scale["photo"] - 0.5
        )
        put("matches", draw_matches(left, photo, k0, k1, images.inliers))
    logger.debug("frame %s: wrote %d report assets", record["frame_id"], len(written))
    return written


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
    out_dir: str | Path, assets: Mapping[str, Mapping[str, str]] | None
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
    if missing:
        logger.warning("%d report assets are missing or unsafe and are not shown", missing)
    return out
