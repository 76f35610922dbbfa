"""Enhance a folder of renders with the nearest training photos (MaRINeR's second application:
better novel views of a NeRF / mesh); the command ``pgt-check enhance RENDERS MODEL --out DIR``
(``pgt_check.commands.enhance``) wraps ``enhance_folder``.

Inputs and the naming convention:

* ``RENDERS``: a folder of rendered images (``.png``/``.jpg``/``.jpeg``, top level only), for
  example a nerfstudio ``ns-render dataset`` output.
* ``MODEL``: the training images with their poses: a nerfstudio ``transforms.json``, a COLMAP
  model or any pose file ``pgt_check.io.read_trajectory`` reads (``--format``, ``--images``,
  ``--sensors``, ``--camera``, ``--dataparser-transforms`` as for ``pgt-check``). Its frames
  whose photo exists are the references.
* The pose of a render: without ``--render-poses``, the render is named like a model image
  (same file name without the extension, e.g. ``frame_00012.png`` for ``images/frame_00012.jpg``;
  or the frame id) and takes that image's pose. With ``--render-poses FILE`` (any format
  ``read_trajectory`` reads, ``--render-poses-format``), the render is named like an image or
  frame id of that file. A render that matches no pose is skipped (listed in references.csv).
* Reference: the model photo nearest to the render's pose, by the validator's distance
  (``pgt_check.enhance.reference``): ``|dc| / translation_scale + angle / rotation_scale_deg``
  (translation_scale default: 10 % of the extent of the training cameras), at most
  ``--max-rotation-deg`` apart. The photo of the render's own view (same name, or same pose) is
  the view's ground truth and is not used unless ``--allow-same-view`` (an upper bound).

Methods: ``mariner`` (default; the learned enhancer, shipped weights unless ``--weights``; it
works at ``--short-side`` and its result is resized back to the render's size) or ``reproject``
(needs ``--mesh``: the reference photo projected through the mesh into the render's view; the
render's size must have the aspect ratio of its camera).

Outputs in ``--out``: ``images/<render name>.png`` (enhanced, render size), ``references.csv``
(render, pose, reference, distances, status) and, with ``--gt DIR`` (photos named like the
renders, resized to the render's size when they differ), ``metrics.csv`` (per render: PSNR-Y,
SSIM-Y, LPIPS-Alex of the raw render and of the enhanced image against the photo) and
``metrics.md`` (the same with means).
"""

from __future__ import annotations

import argparse
import logging
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from pgt_check.common.files import (
    atomic_write_bytes,
    atomic_write_text,
    check_inputs_not_outputs,
    safe_text,
)
from pgt_check.enhance.refs import (  # re-exported: the folder enhancement's public helpers
    IMAGE_SUFFIXES,
    RenderItem,
    find_renders,
    frame_index,
    nearest_references,
    pose_renders,
)
from pgt_check.errors import InputError, SetupError
from pgt_check.output_layout import ENHANCE_OUTPUTS
from pgt_check.types import Camera, Frame

__all__ = [
    "IMAGE_SUFFIXES",
    "METRIC_COLUMNS",
    "REFERENCE_COLUMNS",
    "RenderItem",
    "enhance_folder",
    "find_gt",
    "find_renders",
    "frame_index",
    "metrics_markdown",
    "nearest_references",
    "pose_renders",
    "summary_lines",
]

logger = logging.getLogger(__name__)


REFERENCE_COLUMNS = ("render", "pose", "reference", "reference_dt", "reference_drot_deg",
                     "status")
METRIC_COLUMNS = ("render", "reference", "psnr_y_raw", "psnr_y_enhanced", "ssim_y_raw",
                  "ssim_y_enhanced", "lpips_raw", "lpips_enhanced")


def _render_camera(frame: Frame, image: np.ndarray) -> Camera:
    """The render's pinhole camera at the render file's size (same aspect ratio required)."""
    cam = frame.camera.as_pinhole()
    h, w = image.shape[:2]
    if (w, h) == (cam.width, cam.height):
        return cam
    if abs(w / h - cam.width / cam.height) > 0.01 * cam.width / cam.height:
        raise InputError(f"render {w}x{h} does not have the aspect ratio of its camera "
                         f"{cam.width}x{cam.height}")
    return cam.scaled(w / cam.width, h / cam.height)


class _Reprojector:
    """The reprojection method for renders that come from files (the mesh gives the depth)."""

    def __init__(self, mesh: str | Path, shading: str = "auto") -> None:
        from pgt_check.render import load_mesh, make_renderer

        if not Path(mesh).is_file():
            raise InputError(f"mesh not found: {mesh}")
        try:
            loaded = load_mesh(mesh, shading=shading)
        except (InputError, MemoryError):
            raise
        except Exception as err:  # trimesh raises many types for files it cannot read
            raise InputError(f"{mesh}: cannot load mesh ({type(err).__name__}: "
                             f"{(str(err).splitlines() or [''])[0][:160]})") from None
        try:
            self.renderer = make_renderer(loaded)
        except (InputError, MemoryError):
            raise
        except Exception as err:
            raise SetupError(f"cannot build the renderer: {type(err).__name__}: {err}") from None

    def __call__(self, render: np.ndarray, frame: Frame, photo: np.ndarray,
                 reference: Frame) -> np.ndarray:
        from pgt_check.enhance.reproject import reproject_reference
        from pgt_check.io.photo import prepare_photo

        cam = _render_camera(frame, render)
        depth = self.renderer.render(cam, frame.world_from_cam).depth
        ref_photo, ref_cam = prepare_photo(photo, reference.camera)
        ref_depth = self.renderer.render(ref_cam, reference.world_from_cam).depth
        image, _ = reproject_reference(render, depth, cam, frame.world_from_cam, ref_photo,
                                       ref_depth, ref_cam, reference.world_from_cam)
        return image

    def close(self) -> None:
        self.renderer.close()


class _Mariner:
    def __init__(self, weights: str | None, device: str, short_side: int,
                 iterations: int | None) -> None:
        from pgt_check.enhance.mariner import MarinerEnhancer

        self.enhancer = MarinerEnhancer(weights=weights, device=device, short_side=short_side,
                                        iterations=iterations)
        if weights is not None and not Path(weights).is_file():
            raise InputError(f"MaRINeR weights not found: {weights}")
        try:
            model = self.enhancer._load()
        except InputError:
            raise
        except Exception as err:  # a file that is not a MaRINeR checkpoint
            raise InputError(f"cannot load MaRINeR weights {weights or '(shipped)'}: "
                             f"{type(err).__name__}: {(str(err).splitlines() or [''])[0][:160]}") from err
        minimum = model.model.cfg.min_reference_size
        if short_side < minimum:
            raise InputError(f"--short-side {short_side} is below MaRINeR's minimum {minimum}")
        if iterations is not None and iterations < 1:
            raise InputError(f"--iterations must be >= 1, got {iterations}")

    def __call__(self, render: np.ndarray, frame: Frame, photo: np.ndarray,
                 reference: Frame) -> np.ndarray:
        return self.enhancer.enhance_image(render, photo)

    def close(self) -> None:
        pass


class _Metrics:
    """PSNR-Y / SSIM-Y (``mariner_core.metrics``) and LPIPS-Alex (optional)."""

    def __init__(self, lpips: bool) -> None:
        try:
            from mariner_core import metrics
        except ImportError as err:
            from pgt_check.errors import MissingExtraError

            raise MissingExtraError(err.name or "torch", "enhance") from err
        self.metrics = metrics
        self.lpips = None
        if lpips:
            try:
                self.lpips = metrics.LPIPS.pretrained("alex")
            except FileNotFoundError as err:
                raise InputError(f"LPIPS weights unavailable ({err}); pass --no-lpips") from err

    def __call__(self, image: np.ndarray, gt: np.ndarray) -> tuple[float, float, float | None]:
        import torch

        m = self.metrics
        psnr = float(m.psnr_y(image, gt)[0])
        ssim = float(m.ssim_y(image, gt)[0])
        lp = None
        if self.lpips is not None:
            with torch.inference_mode():
                a = torch.from_numpy(np.ascontiguousarray(image)).permute(2, 0, 1)[None].float()
                b = torch.from_numpy(np.ascontiguousarray(gt)).permute(2, 0, 1)[None].float()
                lp = float(self.lpips(a, b)[0])
        return psnr, ssim, lp


def find_gt(folder: Path, name: str) -> Path | None:
    for suffix in (*IMAGE_SUFFIXES, *(s.upper() for s in IMAGE_SUFFIXES)):
        p = folder / f"{name}{suffix}"
        if p.is_file():
            return p
    return None


def _fmt(v: float | None, digits: int = 4) -> str:
    return "" if v is None or not math.isfinite(v) else f"{v:.{digits}f}"


def _csv_text(columns: Sequence[str], rows: Sequence[dict[str, Any]]) -> str:
    """references.csv / metrics.csv: cells as in frames.csv (formulas neutralised, one line per
    row, any file name)."""
    from pgt_check.report.outputs import csv_text

    return csv_text(columns, rows)


def _md_cell(value: Any) -> str:
    return safe_text(value).replace("|", "\\|")


def _mean(values: Sequence[float | None]) -> float | None:
    vals = [v for v in values if v is not None and math.isfinite(v)]
    return float(np.mean(vals)) if vals else None


def metrics_markdown(rows: Sequence[dict[str, Any]], method: str) -> str:
    """The metrics table (one row per render, then the means) as Markdown."""
    def num(r: dict[str, Any], k: str) -> float | None:
        v = r.get(k)
        return None if v in (None, "") else float(v)

    lines = [
        f"# Enhanced renders ({method}) against the photos",
        "",
        "PSNR-Y / SSIM-Y on 8-bit BT.601 luma, LPIPS v0.1 AlexNet; at the render's size.",
        "",
        "| render | reference | PSNR-Y raw | PSNR-Y enhanced | SSIM-Y raw | SSIM-Y enhanced "
        "| LPIPS raw | LPIPS enhanced |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(f"| {_md_cell(r['render'])} | {_md_cell(r['reference'])} | " + " | ".join(
            _fmt(num(r, k), 2 if k.startswith("psnr") else 3) or "-" for k in METRIC_COLUMNS[2:]
        ) + " |")
    means = {k: _mean([num(r, k) for r in rows]) for k in METRIC_COLUMNS[2:]}
    lines.append(f"| **mean ({len(rows)})** | | " + " | ".join(
        _fmt(means[k], 2 if k.startswith("psnr") else 3) or "-" for k in METRIC_COLUMNS[2:]
    ) + " |")
    return "\n".join(lines) + "\n"


def _save_png(path: Path, image: np.ndarray) -> None:
    """Write ``image`` as PNG through a temporary file (never through a symlink at ``path``)."""
    from io import BytesIO

    from PIL import Image

    path.parent.mkdir(parents=True, exist_ok=True)
    buf = BytesIO()
    Image.fromarray(np.round(np.clip(image, 0, 1) * 255).astype(np.uint8)).save(buf, "PNG")
    atomic_write_bytes(path, buf.getvalue())


def check_enhance_options(args: argparse.Namespace) -> None:
    """Every numeric option in range, and ``--out`` a folder that holds none of the inputs
    (InputError naming the option)."""
    from pgt_check.config import MAX_IMAGE_SIDE
    from pgt_check.config.load import check_range

    checks = [("--limit", args.limit, 1, None, False), ("--short-side", args.short_side, 1,
              MAX_IMAGE_SIDE, False), ("--iterations", args.iterations, 1, 1000, False),
              ("--max-rotation-deg", args.max_rotation_deg, 0, 180, True),
              ("--translation-scale", args.translation_scale, 0, None, True)]
    try:
        for name, value, lo, hi, lo_open in checks:
            check_range(name, value, lo, hi, lo_open=lo_open)
    except ValueError as err:
        raise InputError(str(err)) from None
    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise InputError(f"--out {out}: exists and is not a folder")
    outputs = ENHANCE_OUTPUTS.paths(out)
    check_inputs_not_outputs(
        [("renders folder", args.renders), ("model", args.model), ("images", args.images),
         ("sensors file", args.sensors), ("render poses", args.render_poses),
         ("--gt folder", args.gt), ("mesh", args.mesh), ("weights", args.weights),
         ("dataparser transforms", args.dataparser_transforms)],
        outputs, "--out",
    )


def _enhance_item(it: RenderItem, method: Any, out: Path, gt_dir: Path | None,
                  metrics: Any) -> tuple[str, dict[str, Any] | None]:
    """Enhance one render that has a reference: writes ``images/<name>.png``; returns its
    status and, when its ground-truth photo is found, its metrics row."""
    from pgt_check.io import load_image
    from pgt_check.io.images import resize_image

    status = it.status
    assert it.reference is not None and it.reference.image_file is not None  # has a reference
    render = load_image(it.file)
    photo = load_image(it.reference.image_file)
    enhanced = method(render, it.frame, photo, it.reference)
    _save_png(out / ENHANCE_OUTPUTS.images_dir / f"{it.name}.png", enhanced)
    gt_file = find_gt(gt_dir, it.name) if gt_dir is not None else None
    if gt_dir is not None and gt_file is None:
        status = "enhanced_no_gt"
    if gt_file is None:
        return status, None
    gt = load_image(gt_file)
    h, w = render.shape[:2]
    gt = resize_image(gt, (w, h), "area" if gt.shape[1] >= w else "cubic")
    raw_m = metrics(render, np.clip(gt, 0, 1))
    enh_m = metrics(enhanced, np.clip(gt, 0, 1))
    return status, {
        "render": it.name, "reference": it.reference.image_path,
        "psnr_y_raw": _fmt(raw_m[0]), "psnr_y_enhanced": _fmt(enh_m[0]),
        "ssim_y_raw": _fmt(raw_m[1]), "ssim_y_enhanced": _fmt(enh_m[1]),
        "lpips_raw": _fmt(raw_m[2]), "lpips_enhanced": _fmt(enh_m[2]),
    }


def _render_items(args: argparse.Namespace, files: Sequence[Path]) -> list[RenderItem]:
    """The renders with their poses (MODEL's, or ``--render-poses``) and nearest reference
    photos; InputError when no render has one."""
    from pgt_check.io import read_trajectory

    extra = {"camera": args.camera} if args.camera else {}
    model = read_trajectory(args.model, args.format, images=args.images, sensors=args.sensors,
                            dataparser_transforms=args.dataparser_transforms, **extra)
    poses = model
    if args.render_poses:
        poses = read_trajectory(args.render_poses, args.render_poses_format, **extra)
    items = pose_renders(files, poses)
    training = [f for f in model.frames if f.image_file is not None and f.image_file.is_file()]
    items = nearest_references(items, training, translation_scale=args.translation_scale,
                               max_rotation_deg=args.max_rotation_deg,
                               allow_same_view=args.allow_same_view)
    if not any(it.reference is not None for it in items):
        raise InputError(f"no render has a model photo within {args.max_rotation_deg:g} deg "
                         "(--max-rotation-deg) to take appearance from")
    return items


def enhance_folder(args: argparse.Namespace) -> dict[str, Any]:
    """Run the subcommand; returns a summary (counts and the metric means)."""
    check_enhance_options(args)
    files = find_renders(args.renders)
    if args.limit is not None:
        files = files[: args.limit]
    gt_dir = None
    if args.gt is not None:
        gt_dir = Path(args.gt)
        if not gt_dir.is_dir():
            raise InputError(f"--gt folder not found: {gt_dir}")
    if args.method == "reproject" and not args.mesh:
        raise InputError("--method reproject needs --mesh")
    items = _render_items(args, files)
    metrics = _Metrics(lpips=not args.no_lpips) if gt_dir is not None else None
    if args.method == "mariner":
        method: Any = _Mariner(args.weights, args.device, args.short_side, args.iterations)
    else:
        method = _Reprojector(args.mesh, args.shading)
    out = Path(args.out)
    ref_rows, metric_rows = [], []
    try:
        for it in items:
            status = it.status
            if it.reference is not None:
                status, metric_row = _enhance_item(it, method, out, gt_dir, metrics)
                if metric_row is not None:
                    metric_rows.append(metric_row)
            ref_rows.append({
                "render": it.file.name,
                "pose": "" if it.frame is None else it.frame.frame_id,
                "reference": "" if it.reference is None else it.reference.image_path,
                "reference_dt": _fmt(it.reference_dt), "reference_drot_deg":
                _fmt(it.reference_drot_deg, 3), "status": status,
            })
    finally:
        method.close()
    out.mkdir(parents=True, exist_ok=True)
    atomic_write_text(out / ENHANCE_OUTPUTS.references_csv, _csv_text(REFERENCE_COLUMNS, ref_rows))
    summary: dict[str, Any] = {
        "renders": len(items), "enhanced": sum(it.reference is not None for it in items),
        "method": args.method, "with_gt": len(metric_rows),
    }
    if metric_rows:
        atomic_write_text(out / ENHANCE_OUTPUTS.metrics_csv, _csv_text(METRIC_COLUMNS, metric_rows))
        atomic_write_text(out / ENHANCE_OUTPUTS.metrics_md,
                          metrics_markdown(metric_rows, args.method))
        for k in METRIC_COLUMNS[2:]:
            summary[k] = _mean([float(r[k]) if r[k] else None for r in metric_rows])
    return summary


def summary_lines(summary: dict[str, Any], out: str | Path) -> list[str]:
    """What ``pgt-check enhance`` prints about a finished ``enhance_folder`` run."""
    lines = [f"pgt-check enhance: {summary['enhanced']} of {summary['renders']} renders enhanced "
             f"({summary['method']}) into {safe_text(Path(out) / 'images')}"]
    if summary["with_gt"]:
        lines.append(
            f"pgt-check enhance: against {summary['with_gt']} photos: PSNR-Y "
            f"{_fmt(summary['psnr_y_raw'], 2)} -> {_fmt(summary['psnr_y_enhanced'], 2)} dB, "
            f"SSIM-Y {_fmt(summary['ssim_y_raw'], 3)} -> {_fmt(summary['ssim_y_enhanced'], 3)}"
            + (f", LPIPS {_fmt(summary['lpips_raw'], 3)} -> "
               f"{_fmt(summary['lpips_enhanced'], 3)}" if summary["lpips_raw"] is not None
               else "")
            + f" ({Path(out) / 'metrics.md'})")
    return lines
