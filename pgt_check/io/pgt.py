"""Brachmann-style pseudo ground truth (visloc_pseudo_gt_limitations): ``rgb_file qw qx qy qz tx ty tz f``.

What the file stores: **cam_from_world** (``p_cam = R(q) p_world + t``), OpenCV camera axes,
Hamilton quaternion with the scalar first, and one focal length ``f`` in pixels. The principal
point is the image centre: (w/2, h/2) in the COLMAP pixel convention, i.e. ((w-1)/2, (h-1)/2) in
OpenCV convention. The image size is read from each image's header.
"""

from __future__ import annotations

import logging
from collections import Counter
from pathlib import Path

import numpy as np

from pgt_check.errors import FormatError, InputError
from pgt_check.geometry.transforms import invert_rigid
from pgt_check.io._text import (
    QuaternionCounter,
    UniqueKeys,
    check_frame_id,
    data_lines,
    parse_float,
    split_row,
)
from pgt_check.io.images import image_size
from pgt_check.types import Camera, Frame, Trajectory

logger = logging.getLogger(__name__)

LAYOUT = "rgb_file qw qx qy qz tx ty tz f"


def read_pgt(path: str | Path, *, images: str | Path | None = None) -> Trajectory:
    """Read a pGT pose file; images are resolved against ``images`` (default: the file's folder).

    Each camera is SIMPLE_PINHOLE(f, (w-1)/2, (h-1)/2) with the size of its image. When an image
    is missing, the size shared by all found images is used (the frame stays, and the missing
    image is reported downstream); if found images differ in size, the frame is skipped. One
    WARNING gives the count of missing images. frame_id and image_path are ``rgb_file``.
    """
    path = Path(path)
    root = Path(images) if images is not None else path.parent
    if not root.is_dir():
        raise InputError(f"{root}: images folder not found")
    rows = _pose_rows(path)
    sizes = _image_sizes(path, rows, root)
    frames = _frames_with_cameras(path, rows, sizes, root)
    logger.info("read %d frames from %s", len(frames), path)
    return Trajectory(
        tuple(frames), source=str(path), format="pgt", metadata={"images_dir": str(root)}
    )


def _pose_rows(path: Path) -> list[tuple[int, str, float, np.ndarray]]:
    """``(line, rgb_file, f, world_from_cam (4, 4))`` of each row of a pGT file."""
    quats = QuaternionCounter(path)
    rows: list[tuple[int, str, float, np.ndarray]] = []
    seen = UniqueKeys(path, "unique image names")
    for line, text in data_lines(path):
        fields = split_row(path, line, text, count=9, sep=None, layout=LAYOUT)
        name = fields[0]
        check_frame_id(path, line, name, what="image name")
        seen.add(name, repr(name), line)
        v = [
            parse_float(path, line, f, n)
            for f, n in zip(fields[1:], LAYOUT.split()[1:], strict=True)
        ]
        cam_from_world = quats.rigid(line, v[:4], v[4:7])
        if v[7] <= 0:
            raise FormatError(path, line, f"expected a positive focal length f; got {fields[8]}")
        rows.append((line, name, v[7], invert_rigid(cam_from_world)))
    quats.report()
    return rows


def _image_sizes(
    path: Path, rows: list[tuple[int, str, float, np.ndarray]], root: Path
) -> dict[str, tuple[int, int]]:
    """(width, height) by rgb_file of the images found under ``root``; InputError if none is."""
    sizes: dict[str, tuple[int, int]] = {}
    for _line, name, _f, _pose in rows:
        try:
            sizes[name] = image_size(root / name)
        except InputError:
            continue
    if not sizes:
        raise InputError(
            f"{path}: none of its {len(rows)} images found under {root} (needed for their size; use --images)"
        )
    return sizes


def _frames_with_cameras(
    path: Path,
    rows: list[tuple[int, str, float, np.ndarray]],
    sizes: dict[str, tuple[int, int]],
    root: Path,
) -> list[Frame]:
    """One Frame per row, in file order, with a SIMPLE_PINHOLE camera of its image's size (one
    WARNING giving the count of missing images)."""
    distinct = set(sizes.values())
    shared = next(iter(distinct)) if len(distinct) == 1 else None
    # a missing image's frame keeps the most common size (it is UNVERIFIABLE image_missing
    # either way, never dropped: the camera only matters once the image is there)
    common = Counter(sizes.values()).most_common(1)[0][0]
    frames: list[Frame] = []
    missing: list[str] = []
    for _line, name, f, world_from_cam in rows:
        if name not in sizes:
            missing.append(name)
        width, height = sizes.get(name, common)
        camera = Camera("SIMPLE_PINHOLE", width, height, (f, (width - 1) / 2.0, (height - 1) / 2.0))
        frames.append(Frame(name, camera, world_from_cam, name, root / name))
    if missing:
        how = (
            "kept with the shared image size" if shared
            else "kept with the most common image size"
        ) + " (UNVERIFIABLE image_missing)"
        logger.warning(
            "%s: %d image(s) not found under %s, %s (first: %s)",
            path,
            len(missing),
            root,
            how,
            missing[0],
        )
    return frames
