"""Training / evaluation data for the MaRINeR enhancer, built from any dataset the validator reads.

For every frame of a trajectory (poses + photos) and a mesh, this writes one ``npz`` file at a
*working size* (shorter side ``short_side``, 160 px by default) holding uint8 RGB images:

* ``photo``: the frame's own photo (the training target),
* ``render``: the coloured mesh rendered at the frame's pose,
* ``render_decimated``: the mesh decimated to ~10 % of its faces (paper augmentation),
* ``render_colourless``: the mesh without colours, shaded exactly as the validator renders a
  colourless mesh (``MeshData.without_colour()``),

plus ``index.json`` (frame ids, timestamps, file names, working size, sources). Renders are made
once, directly at the working size (``camera.scaled``), so training reads only small files.
Variants that the mesh cannot give (a mesh without colours has no coloured render) are stored as
the shaded render and flagged in ``index.json``.

Pairing (which other frame is the reference) and train/validation splits are *not* baked in: they
live in ``mariner_core.data`` (``split_frames``, ``reference_candidates``) so the trainer can draw a
new reference at every sample. Evaluation sets use fixed pairs, see :func:`fixed_offset_pairs`.

CLI::

    python -m pgt_check.enhance.training_data --trajectory T --mesh M --out DIR [--sensors S]

``mariner_core`` never imports ``pgt_check``; the files written here are plain numpy archives.
"""

from __future__ import annotations

import argparse
import json
import logging
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

logger = logging.getLogger(__name__)

__all__ = [
    "VARIANTS",
    "build_frame_cache",
    "fixed_offset_pairs",
    "frame_order_key",
    "main",
    "working_size",
]

#: image keys of every frame file (the photo plus the three render variants)
VARIANTS = ("photo", "render", "render_decimated", "render_colourless")
INDEX_NAME = "index.json"


def working_size(width: int, height: int, short_side: int) -> tuple[int, int]:
    """(width, height) with the shorter side equal to ``short_side``, aspect kept (rounded)."""
    f = short_side / min(width, height)
    return max(1, round(width * f)), max(1, round(height * f))


def frame_order_key(frame: object, position: int) -> float:
    """Sort key / frame distance unit: the frame's timestamp (frame index), else its position."""
    ts = getattr(frame, "timestamp", None)
    return float(ts) if ts is not None else float(position)


def _to_uint8(img: np.ndarray) -> np.ndarray:
    return np.clip(np.round(img * 255.0), 0, 255).astype(np.uint8)


def _resize(img: np.ndarray, width: int, height: int) -> np.ndarray:
    """Area when shrinking, cubic when enlarging (the one resize helper of ``io.images``)."""
    from pgt_check.io.images import resize_image

    return resize_image(img, (width, height), "area" if width < img.shape[1] else "cubic")


def _variant_meshes(base: Any, variants: Sequence[str], decimate_fraction: float) -> dict:
    """The mesh rendered for each render variant (colourless meshes render shaded)."""
    meshes = {}
    coloured = base.shading != "shaded"
    if "render" in variants:
        meshes["render"] = base if coloured else base.without_colour()
    if "render_decimated" in variants:
        t0 = time.perf_counter()
        dec = base.decimated(decimate_fraction)
        meshes["render_decimated"] = dec if coloured else dec.without_colour()
        logger.info(
            "decimated %d -> %d faces in %.1f s",
            base.num_faces,
            dec.num_faces,
            time.perf_counter() - t0,
        )
    if "render_colourless" in variants:
        meshes["render_colourless"] = base.without_colour()
    return meshes


def _write_frame(path: Path, frame: Any, size: tuple[int, int], renderers: dict) -> None:
    """One cache file: the photo and each variant's render at ``size``, as uint8 arrays."""
    from pgt_check.io import load_image

    if frame.image_file is None:
        raise ValueError(f"frame {frame.frame_id} has no image file")
    w, h = size
    cam = frame.camera
    photo = load_image(frame.image_file)
    data = {"photo": _to_uint8(_resize(photo, w, h))}
    cam_w = cam.scaled(w / cam.width, h / cam.height)
    for k, r in renderers.items():
        data[k] = _to_uint8(r.render(cam_w, frame.world_from_cam).rgb)
    tmp = path.with_name(path.name + ".tmp.npz")
    np.savez(tmp, **data)  # type: ignore[arg-type]  # numpy's stub: named arrays are fine
    tmp.replace(path)


def build_frame_cache(
    trajectory: str | Path,
    mesh: str | Path,
    out_dir: str | Path,
    *,
    sensors: str | Path | None = None,
    images: str | Path | None = None,
    short_side: int = 160,
    decimate_fraction: float = 0.1,
    variants: Sequence[str] = VARIANTS,
    max_frames: int | None = None,
    overwrite: bool = False,
) -> Path:
    """Render and store every frame at working size; returns the path of ``index.json``.

    Existing frame files are reused unless ``overwrite`` (the cache: renders are made once).
    ``variants`` selects which images to store ("photo" is always stored).
    """
    from pgt_check.io import read_trajectory
    from pgt_check.render import load_mesh, make_renderer

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    variants = _checked_variants(variants)
    traj = read_trajectory(trajectory, sensors=sensors, images=images)
    frames = sorted(
        ((frame_order_key(f, i), f) for i, f in enumerate(traj.frames)), key=lambda kv: kv[0]
    )
    if max_frames is not None:
        frames = frames[:max_frames]
    base = load_mesh(mesh)
    coloured = base.shading != "shaded"
    meshes = _variant_meshes(base, variants, decimate_fraction)
    renderers = {k: make_renderer(m) for k, m in meshes.items()}
    records = _write_frames(frames, out, short_side, renderers, overwrite)
    index = {
        "trajectory": str(trajectory),
        "sensors": None if sensors is None else str(sensors),
        "mesh": str(mesh),
        "short_side": short_side,
        "decimate_fraction": decimate_fraction,
        "variants": list(variants),
        "mesh_coloured": coloured,
        "frames": records,
    }
    index_path = out / INDEX_NAME
    index_path.write_text(json.dumps(index, indent=1))
    logger.info("wrote %d frames to %s", len(records), out)
    return index_path


def _checked_variants(variants: Sequence[str]) -> tuple[str, ...]:
    """``variants`` with "photo" first and without repeats; ValueError for an unknown one."""
    variants = tuple(dict.fromkeys(("photo", *variants)))
    unknown = sorted(set(variants) - set(VARIANTS))
    if unknown:
        raise ValueError(f"unknown variant(s) {unknown} (allowed: {VARIANTS})")
    return variants


def _write_frames(
    frames: Sequence[tuple[float, Any]],
    out: Path,
    short_side: int,
    renderers: dict,
    overwrite: bool,
) -> list[dict[str, Any]]:
    """Write the cache file of each (order key, frame), keeping existing ones unless
    ``overwrite``, and close the renderers; returns the frames' ``index.json`` records."""
    records = []
    t0 = time.perf_counter()
    try:
        for n, (key, frame) in enumerate(frames):
            name = f"frame_{n:06d}.npz"
            path = out / name
            cam = frame.camera
            w, h = working_size(cam.width, cam.height, short_side)
            records.append(
                {
                    "frame_id": frame.frame_id,
                    "t": key,
                    "file": name,
                    "width": w,
                    "height": h,
                    "image_path": frame.image_path,
                }
            )
            if path.is_file() and not overwrite:
                continue
            _write_frame(path, frame, (w, h), renderers)
            if (n + 1) % 50 == 0:
                logger.info("%d/%d frames (%.1f s)", n + 1, len(frames), time.perf_counter() - t0)
    finally:
        for r in renderers.values():
            r.close()
    return records


def fixed_offset_pairs(n: int, offset: int) -> list[tuple[int, int]]:
    """Evaluation pairs (frame, reference) ``i -> i + offset``, or ``i - offset`` at the end.

    Positions index the time-sorted frames; ``offset`` >= 1 and < n.
    """
    if not 1 <= offset < n:
        raise ValueError(f"offset must be in [1, {n - 1}], got {offset}")
    return [(i, i + offset if i + offset < n else i - offset) for i in range(n)]


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--trajectory", required=True)
    parser.add_argument("--mesh", required=True)
    parser.add_argument("--out", required=True)
    parser.add_argument("--sensors", default=None)
    parser.add_argument("--images", default=None)
    parser.add_argument("--short-side", type=int, default=160)
    parser.add_argument("--decimate", type=float, default=0.1)
    parser.add_argument("--variants", default=",".join(VARIANTS))
    parser.add_argument("--max-frames", type=int, default=None)
    parser.add_argument("--overwrite", action="store_true")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s: %(message)s")
    build_frame_cache(
        args.trajectory,
        args.mesh,
        args.out,
        sensors=args.sensors,
        images=args.images,
        short_side=args.short_side,
        decimate_fraction=args.decimate,
        variants=[v for v in args.variants.split(",") if v],
        max_frames=args.max_frames,
        overwrite=args.overwrite,
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
