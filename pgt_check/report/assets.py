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
from collections.abc import Callable, Iterable, Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from pgt_check.config import VerdictConfig
    from pgt_check.measure.paths import FrameImages
    from pgt_check.measure.record import FrameMeasurement
    from pgt_check.verdict.result import RunResult

from pgt_check.output_layout import OUTPUTS
from pgt_check.report.drawing import (  # re-exported: callers and tests import them here
    ARROW_GRID,
    PANEL_MAX,
    PATH_BGR,
    TILE_MAX,
    arrow_magnification,
    checkerboard,
    diff_tile,
    difference_image,
    draw_arrows,
    fit,
    frame_paths,
    grid_points,
    homography_displacements,
    resize,
    scaled_path,
    to_uint8_bgr,
    write_jpeg,
)

logger = logging.getLogger(__name__)

__all__ = [
    "ARROW_GRID", "ASSET_KINDS", "PANEL_MAX", "PATH_BGR",
    "TILE_MAX", "PanelWriter", "arrow_magnification", "asset_stem", "checkerboard",
    "difference_image", "draw_arrows", "existing_assets", "grid_points",
    "homography_displacements", "load_assets_index", "main_pass_assets", "manifest_path",
    "prune_panels", "select_detail_frames", "write_assets_index", "write_frame_assets",
]

MANIFEST_VERSION = 1
#: asset kinds in display order
ASSET_KINDS = (
    "render", "enhanced", "photo", "diff", "blend", "checker", "arrows_raw", "arrows_enhanced",
)

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
    rel_dir = OUTPUTS.panels_dir
    written: dict[str, str] = {}

    def put(kind: str, bgr: np.ndarray) -> None:
        rel = f"{rel_dir}/{stem}_{kind}.jpg"
        write_jpeg(out_dir / rel, bgr)
        written[kind] = rel

    panels: dict[str, np.ndarray] = {}
    for kind in ("render", "enhanced", "photo"):
        img = getattr(images, kind, None)
        if img is None:
            continue
        panels[kind] = fit(to_uint8_bgr(img), PANEL_MAX)
        put(kind, panels[kind])
    if "render" in panels and "photo" in panels:
        render, photo = panels["render"], panels["photo"]
        if render.shape != photo.shape:
            render = resize(render, (photo.shape[1], photo.shape[0]))
        put("diff", diff_tile(render, photo))
        blend = (render.astype(np.uint16) + photo.astype(np.uint16) + 1) // 2
        put("blend", blend.astype(np.uint8))
        put("checker", checkerboard(render, photo))
    if "photo" in panels:
        photo = panels["photo"]
        s = photo.shape[1] / np.asarray(images.photo).shape[1]
        paths = {k: scaled_path(v, s) for k, v in frame_paths(images).items()}
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
    return Path(out_dir) / OUTPUTS.panels_dir / f"{asset_stem(frame_id)}.json"


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
    folder = Path(out_dir) / OUTPUTS.panels_dir
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
    return Path(out_dir) / OUTPUTS.assets_index


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
        and p.parts[0] == OUTPUTS.assets_dir
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


def report_panels(
    out_dir: str | Path,
    result: RunResult,
    max_details: int,
    fingerprint: str,
    frame_images: Callable[[str], FrameImages | None],
) -> dict[str, dict[str, str]]:
    """Panels of the report's detail frames of ``result`` (``select_detail_frames``): those
    written during the main pass (``PanelWriter``) are reused; ``frame_images(frame_id)``
    measures a selected frame still without panels again and returns its images (None: none
    to show). Panels of frames that were not selected are deleted."""
    out = Path(out_dir)
    rows = result.rows()
    chosen = select_detail_frames(rows, max_details=max_details)
    assets = main_pass_assets(out, chosen, fingerprint)
    missing = [fid for fid in chosen if fid not in assets]
    row_by_id = {r["frame_id"]: r for r in rows}
    n_again = 0
    for fid in missing:
        images = frame_images(fid)
        if images is None:
            continue
        n_again += 1
        assets[fid] = write_frame_assets(out, row_by_id[fid], images)
    logger.info("report: %d detail frames, %d with panels from the main pass, %d measured again",
                len(chosen), len(chosen) - len(missing), n_again)
    removed = prune_panels(out, chosen)
    if removed:
        logger.debug("removed %d panel files of frames not shown", removed)
    return {fid: assets[fid] for fid in chosen if fid in assets}
