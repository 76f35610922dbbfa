"""TUM RGB-D trajectories: ``timestamp tx ty tz qx qy qz qw`` per line.

What the file stores: **world_from_cam** (camera-to-world, ``X_world = R(q) X_cam + t``), OpenCV
camera axes, Hamilton quaternion with the scalar **last**. It stores no intrinsics (a camera must
be given, OpenCV pixel convention after ``parse_camera_spec``) and no image names: images are
matched by timestamp from a folder (number in each file stem) or a list file (``timestamp path``,
as TUM's ``rgb.txt``).
"""

from __future__ import annotations

import logging
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pgt_check.errors import InputError
from pgt_check.io._text import (
    QuaternionCounter,
    UniqueKeys,
    data_lines,
    is_integer_token,
    parse_float,
    parse_timestamp,
    split_row,
)
from pgt_check.io.camera import parse_camera_spec
from pgt_check.io.images import IMAGE_EXTENSIONS
from pgt_check.types import Camera, Frame, Trajectory

logger = logging.getLogger(__name__)

#: default largest |pose time - image time| (seconds) for a match of non-integer timestamps
MAX_TIME_DIFF = 0.02

_NUMBER = re.compile(r"\d+(?:\.\d+)?")


@dataclass(frozen=True)
class TimedImage:
    timestamp: float
    integer: bool
    path_text: str
    file: Path


def stem_timestamp(name: str) -> str | None:
    """The number in an image file stem, as text: ``1305031102.175304.png`` -> ``1305031102.175304``,
    ``frame-000010.color.jpg`` -> ``000010`` (the last number when there are several)."""
    stem = name
    while Path(stem).suffix and not Path(stem).suffix[1:].isdigit():
        stem = Path(stem).stem
    if _NUMBER.fullmatch(stem):
        return stem
    numbers = _NUMBER.findall(stem)
    return numbers[-1] if numbers else None


def images_from_folder(folder: Path) -> list[TimedImage]:
    """Images in a folder, timed by the number in their stem (files without one are ignored)."""
    found: dict[float, TimedImage] = {}
    for file in sorted(folder.iterdir()):
        if not file.is_file() or file.suffix.lower() not in IMAGE_EXTENSIONS:
            continue
        token = stem_timestamp(file.name)
        if token is None:
            logger.debug("ignoring %s: no number in its name", file)
            continue
        stamp = float(token)
        if stamp in found:
            raise InputError(
                f"{folder}: two images for timestamp {token}: {found[stamp].file.name} and {file.name}; "
                "pass a list file (timestamp path) as images"
            )
        found[stamp] = TimedImage(stamp, is_integer_token(token), file.name, file)
    if not found:
        raise InputError(f"{folder}: no image file with a number in its name")
    return list(found.values())


def images_from_list(path: Path) -> list[TimedImage]:
    """A TUM ``rgb.txt``-style list: ``timestamp path`` per line, paths relative to its folder."""
    out: list[TimedImage] = []
    seen = UniqueKeys(path, "unique timestamps")
    for line, text in data_lines(path):
        fields = split_row(path, line, text, count=2, sep=None, layout="timestamp image_path")
        stamp = parse_timestamp(path, line, fields[0])
        seen.add(stamp, fields[0], line)
        out.append(
            TimedImage(stamp, is_integer_token(fields[0]), fields[1], path.parent / fields[1])
        )
    return out


def match_images(
    stamps: list[tuple[float, bool]], images: list[TimedImage], max_time_diff: float
) -> list[TimedImage | None]:
    """For each (timestamp, is_integer) the nearest image within ``max_time_diff`` (exact if both
    are integers), else None."""
    ordered = sorted(images, key=lambda im: im.timestamp)
    times = np.array([im.timestamp for im in ordered])
    exact = {im.timestamp: im for im in ordered if im.integer}
    out: list[TimedImage | None] = []
    for stamp, integer in stamps:
        if integer and exact:
            out.append(exact.get(stamp))
            continue
        i = int(np.searchsorted(times, stamp))
        best = min(
            (j for j in (i - 1, i) if 0 <= j < len(times)), key=lambda j: abs(times[j] - stamp)
        )
        out.append(ordered[best] if abs(times[best] - stamp) <= max_time_diff else None)
    return out


def read_tum(
    path: str | Path,
    *,
    camera: Camera | str | None,
    images: str | Path | None = None,
    max_time_diff: float = MAX_TIME_DIFF,
) -> Trajectory:
    """Read a TUM trajectory; ``camera`` (Camera or spec string) is required.

    ``images``: a folder or a list file; default ``rgb.txt`` beside the trajectory, else an
    ``images/`` folder beside it. frame_id is the timestamp as written. A pose with no image within
    ``max_time_diff`` seconds (exact match when both timestamps are integers) stays a frame
    without an image (``image_file`` None: UNVERIFIABLE image_missing, counted by the gate), with
    one WARNING giving the count; no pose matching any image is an InputError.
    """
    path = Path(path)
    if camera is None:
        raise InputError(
            f"{path}: TUM trajectories store no intrinsics; --camera is required (e.g. PINHOLE,640,480,525,525,320,240)"
        )
    if isinstance(camera, str):
        camera = parse_camera_spec(camera)
    rows = _pose_rows(path)
    images = _images_source(path, images)
    if images.is_dir():
        timed = images_from_folder(images)
    elif images.is_file():
        timed = images_from_list(images)
    else:
        raise InputError(f"{images}: images folder or list file not found")
    matched = match_images([(s, is_integer_token(t)) for _, t, s, _ in rows], timed, max_time_diff)
    if not any(image is not None for image in matched):
        raise InputError(
            f"{path}: no pose matched an image in {images} (tolerance {max_time_diff} s)"
        )
    frames = _frames_with_images(path, camera, rows, matched, images)
    frames.sort(key=lambda f: f.timestamp)  # type: ignore[arg-type, return-value]  # all set
    logger.info("read %d frames from %s", len(frames), path)
    return Trajectory(
        tuple(frames), source=str(path), format="tum", metadata={"images": str(images)}
    )


def _pose_rows(path: Path) -> list[tuple[int, str, float, np.ndarray]]:
    """``(line, timestamp text, timestamp, world_from_cam (4, 4))`` of each row of a TUM file."""
    quats = QuaternionCounter(path)
    rows: list[tuple[int, str, float, np.ndarray]] = []
    seen = UniqueKeys(path, "unique timestamps")
    for line, text in data_lines(path):
        fields = split_row(
            path, line, text, count=8, sep=None, layout="timestamp tx ty tz qx qy qz qw"
        )
        stamp = parse_timestamp(path, line, fields[0])
        seen.add(stamp, fields[0], line)
        v = [
            parse_float(path, line, f, n)
            for f, n in zip(fields[1:], ("tx", "ty", "tz", "qx", "qy", "qz", "qw"), strict=True)
        ]
        rows.append((line, fields[0], stamp, quats.rigid(line, (v[6], v[3], v[4], v[5]), v[:3])))
    quats.report()
    return rows


def _images_source(path: Path, images: str | Path | None) -> Path:
    """The images folder or list file: ``images`` if given, else ``rgb.txt`` or ``images/``
    beside the trajectory (InputError if neither exists)."""
    if images is None:
        beside = [path.parent / "rgb.txt", path.parent / "images"]
        found = next((p for p in beside if p.exists()), None)
        if found is None:
            raise InputError(
                f"{path}: no images given (--images) and no rgb.txt or images/ beside it"
            )
        images = found
    return Path(images)


def _frames_with_images(
    path: Path,
    camera: Camera,
    rows: list[tuple[int, str, float, np.ndarray]],
    matched: list[TimedImage | None],
    images: Path,
) -> list[Frame]:
    """One Frame per pose row, in file order, with its matched image or none (one WARNING
    giving the count of poses without one)."""
    frames: list[Frame] = []
    unmatched: list[str] = []
    for (_line, token, stamp, world_from_cam), image in zip(rows, matched, strict=True):
        if image is None:  # kept: checked as UNVERIFIABLE image_missing, never dropped
            unmatched.append(token)
            frames.append(Frame(token, camera, world_from_cam, "", None, stamp))
            continue
        frames.append(Frame(token, camera, world_from_cam, image.path_text, image.file, stamp))
    if unmatched:
        logger.warning(
            "%s: %d of %d pose(s) have no image in %s (first: %s); they are UNVERIFIABLE "
            "image_missing",
            path,
            len(unmatched),
            len(rows),
            images,
            unmatched[0],
        )
    return frames
