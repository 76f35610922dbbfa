"""Format detection and the one entry point ``read_trajectory``."""

from __future__ import annotations

import logging
from collections.abc import Callable
from pathlib import Path

from pgt_check.common.files import MAX_INPUT_TEXT_BYTES, load_json_limited
from pgt_check.errors import InputError
from pgt_check.io._text import check_frame_ids, read_text
from pgt_check.io.colmap import colmap_model_dir, read_colmap
from pgt_check.io.hloc import read_hloc
from pgt_check.io.lamar import read_lamar
from pgt_check.io.nerfstudio import read_nerfstudio
from pgt_check.io.pgt import read_pgt
from pgt_check.io.tum import read_tum
from pgt_check.registry import FORMATS
from pgt_check.types import Camera, Trajectory

logger = logging.getLogger(__name__)


#: how many data rows detect_format looks at
_SNIFF_ROWS = 5


def _is_number(token: str) -> bool:
    try:
        float(token)
    except ValueError:
        return False
    return True


def _row_format(text: str) -> str | None:
    """The text format one data row fits, or None."""
    if "," in text:
        fields = [f.strip() for f in text.split(",")]
        if (
            len(fields) == 9
            and _is_number(fields[0])
            and fields[1]
            and not _is_number(fields[1])
            and all(_is_number(f) for f in fields[2:])
        ):
            return "lamar"
        return None
    tokens = text.split()
    if len(tokens) == 8 and all(_is_number(t) for t in tokens):
        return "tum"
    if len(tokens) == 9 and not _is_number(tokens[0]) and all(_is_number(t) for t in tokens[1:]):
        return "pgt"
    if len(tokens) == 8 and not _is_number(tokens[0]) and all(_is_number(t) for t in tokens[1:]):
        return "hloc"
    return None


def detect_format(path: str | Path) -> str:
    """Guess the format of a trajectory path: one of ``FORMATS``.

    A directory with cameras.txt/.bin is COLMAP (also any file of such a model, and a project root
    with sparse/0/ or sparse/); a directory with trajectories.txt is LaMAR, with transforms.json
    nerfstudio; a ``.json`` with "frames" is nerfstudio; a text file is judged by its first data
    rows: 9 comma-separated fields with a timestamp and a device id -> lamar, 8 whitespace numbers
    -> tum, a path and 8 numbers -> pgt, a path and 7 numbers -> hloc.
    Raises InputError naming the file and the formats tried.
    """
    path = Path(path)
    if not path.exists():
        raise InputError(f"{path}: not found")
    if colmap_model_dir(path) is not None:
        return "colmap"
    if path.is_dir():
        if (path / "trajectories.txt").is_file():
            return "lamar"
        if (path / "transforms.json").is_file():
            return "nerfstudio"
        raise InputError(
            f"{path}: cannot tell the format of this directory (tried colmap: cameras.txt/.bin, "
            "lamar: trajectories.txt, nerfstudio: transforms.json)"
        )
    if path.suffix.lower() == ".json":
        try:
            data = load_json_limited(path, MAX_INPUT_TEXT_BYTES)
        except InputError as err:
            raise InputError(f"{path}: cannot tell the format: not readable JSON ({err})") from None
        if isinstance(data, dict) and "frames" in data:
            return "nerfstudio"
        raise InputError(
            f"{path}: cannot tell the format: JSON without a 'frames' list (tried nerfstudio)"
        )
    try:
        lines = read_text(path)
    except InputError as err:
        raise InputError(f"{path}: cannot tell the format: {err}") from None
    rows = [s for s in (raw.strip() for raw in lines) if s and not s.startswith("#")][:_SNIFF_ROWS]
    # Rows that fit no format are left to the reader, which names their line; rows that fit
    # two different formats make the file ambiguous.
    kinds = {k for k in (_row_format(row) for row in rows) if k is not None}
    if len(kinds) == 1:
        return kinds.pop()
    first = rows[0][:80] if rows else "(no data rows)"
    raise InputError(
        f"{path}: cannot tell the format (tried lamar: 'timestamp, device, qw..tz'; "
        f"tum: 'timestamp tx ty tz qx qy qz qw'; pgt: 'rgb_file qw qx qy qz tx ty tz f'; "
        f"hloc: 'name qw qx qy qz tx ty tz'; "
        f"colmap; nerfstudio); first data row: {first!r}"
    )


def read_trajectory(
    path: str | Path,
    format: str = "auto",  # noqa: A002 (public keyword, mirrors --format)
    *,
    images: str | Path | None = None,
    camera: Camera | str | None = None,
    sensors: str | Path | None = None,
    dataparser_transforms: str | Path | None = None,
) -> Trajectory:
    """Read any supported pose file into a Trajectory of world_from_cam frames (OpenCV axes and
    pixel convention).

    ``format``: "auto" (``detect_format``) or one of ``FORMATS``. ``images``: folder (or list
    file for tum/lamar) to resolve images; ``camera``: intrinsics for tum and hloc (Camera or
    ``"MODEL,w,h,params"`` spec in COLMAP convention); ``sensors``: a LaMAR sensors file that
    overrides the paired one, or for hloc a COLMAP model / query list with intrinsics;
    ``dataparser_transforms``: nerfstudio's ``dataparser_transforms.json`` to undo. An option a
    format does not use is an InputError.
    """
    if format not in ("auto", *FORMATS):
        raise InputError(
            f"unknown trajectory format {format!r} (allowed: auto, {', '.join(FORMATS)})"
        )
    fmt = detect_format(path) if format == "auto" else format
    if format == "auto":
        logger.info("%s: detected format %s", path, fmt)
    if camera is not None and fmt not in ("tum", "hloc"):
        raise InputError(
            f"--camera applies to TUM and hloc trajectories only; {path} is {fmt}, which stores "
            "its intrinsics"
        )
    if sensors is not None and fmt not in ("lamar", "hloc"):
        raise InputError(f"--sensors applies to LaMAR and hloc trajectories only; {path} is {fmt}")
    if dataparser_transforms is not None and fmt != "nerfstudio":
        raise InputError(
            f"--dataparser-transforms applies to nerfstudio trajectories only; {path} is {fmt}"
        )
    readers: dict[str, Callable[[], Trajectory]] = {
        "lamar": lambda: read_lamar(path, sensors=sensors, images=images),
        "colmap": lambda: read_colmap(path, images=images),
        "tum": lambda: read_tum(path, camera=camera, images=images),
        "pgt": lambda: read_pgt(path, images=images),
        "nerfstudio": lambda: read_nerfstudio(
            path, images=images, dataparser_transforms=dataparser_transforms
        ),
        "hloc": lambda: read_hloc(path, camera=camera, sensors=sensors, images=images),
    }
    traj = readers[fmt]()
    check_frame_ids(traj.frames, traj.source or path)  # COLMAP (names read by pycolmap)
    return traj
