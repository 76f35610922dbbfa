"""hloc localization results (``results.txt``): ``name qw qx qy qz tx ty tz`` per line.

What the file stores: **cam_from_world** (``p_cam = R(q) p_world + t``), OpenCV camera axes,
Hamilton quaternion with the scalar first, as in COLMAP's images.txt. It stores no intrinsics;
they come from one of:

* ``camera``: one Camera (or ``"MODEL,w,h,params"`` spec, COLMAP convention) for every image;
* ``sensors``: a COLMAP model (folder, one of its files, or project root) whose images are
  named as in the results (a model with a single camera also covers names it lacks), or an hloc
  query list with intrinsics (``name MODEL width height params...`` per line, COLMAP pixel
  convention, as hloc's ``queries_with_intrinsics.txt``).
"""

from __future__ import annotations

import logging
from pathlib import Path

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
from pgt_check.io.camera import camera_from_colmap, parse_camera_spec
from pgt_check.io.colmap import cameras_by_image_name, colmap_model_dir
from pgt_check.types import Camera, Frame, Trajectory

logger = logging.getLogger(__name__)

LAYOUT = "name qw qx qy qz tx ty tz"


def read_query_intrinsics(path: Path) -> dict[str, Camera]:
    """An hloc query list with intrinsics: ``name MODEL width height params...`` per line."""
    cameras: dict[str, Camera] = {}
    seen = UniqueKeys(path, "unique image names")
    for line, text in data_lines(path):
        fields = text.split()
        if len(fields) < 5:
            raise FormatError(
                path, line, f"expected name MODEL width height params...; got {len(fields)} fields"
            )
        name, model = fields[0], fields[1]
        seen.add(name, repr(name), line)
        width = parse_float(path, line, fields[2], "width")
        height = parse_float(path, line, fields[3], "height")
        params = [parse_float(path, line, p, "camera parameter") for p in fields[4:]]
        cameras[name] = camera_from_colmap(path, line, model, width, height, params)
    return cameras


def _intrinsics(
    path: Path, camera: Camera | str | None, sensors: str | Path | None
) -> tuple[dict[str, Camera], Camera | None, str]:
    """(camera by image name, fallback camera for other names, description of the source)."""
    if camera is not None and sensors is not None:
        raise InputError(f"{path}: give --camera or --sensors for hloc results, not both")
    if camera is not None:
        cam = parse_camera_spec(camera) if isinstance(camera, str) else camera
        return {}, cam, "the given camera"
    if sensors is None:
        raise InputError(
            f"{path}: hloc results store no intrinsics; give --sensors (a COLMAP model or an hloc "
            "query list with intrinsics) or --camera (e.g. SIMPLE_RADIAL,1024,768,900,512,384,0)"
        )
    sensors = Path(sensors)
    if not sensors.exists():
        raise InputError(f"{sensors}: intrinsics file or COLMAP model not found")
    if colmap_model_dir(sensors) is not None:
        by_name, cameras = cameras_by_image_name(sensors)
        return by_name, cameras[0] if len(cameras) == 1 else None, f"COLMAP model {sensors}"
    return read_query_intrinsics(sensors), None, f"query list {sensors}"


def read_hloc(
    path: str | Path,
    *,
    camera: Camera | str | None = None,
    sensors: str | Path | None = None,
    images: str | Path | None = None,
) -> Trajectory:
    """Read hloc ``results.txt`` into world_from_cam frames (intrinsics: see module docstring).

    frame_id and image_path are the names as written; image files are resolved against
    ``images`` (default: the results file's folder). Frames keep the file's order. A name with
    no camera in ``sensors`` is a FormatError naming its line.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: hloc results file not found")
    by_name, fallback, source = _intrinsics(path, camera, sensors)
    root = Path(images) if images is not None else path.parent
    if images is not None and not root.is_dir():
        raise InputError(f"{root}: images folder not found")
    quats = QuaternionCounter(path)
    seen = UniqueKeys(path, "unique image names")
    frames: list[Frame] = []
    for line, text in data_lines(path):
        fields = split_row(path, line, text, count=8, sep=None, layout=LAYOUT)
        name = fields[0]
        check_frame_id(path, line, name, what="image name")
        seen.add(name, repr(name), line)
        v = [
            parse_float(path, line, f, n)
            for f, n in zip(fields[1:], LAYOUT.split()[1:], strict=True)
        ]
        cam = by_name.get(name, fallback)
        if cam is None:
            raise FormatError(path, line, f"expected an image named in {source}; got {name!r}")
        world_from_cam = invert_rigid(quats.rigid(line, v[:4], v[4:]))
        frames.append(Frame(name, cam, world_from_cam, name, root / name))
    quats.report()
    logger.info("read %d frames from %s (intrinsics: %s)", len(frames), path, source)
    return Trajectory(
        tuple(frames),
        source=str(path),
        format="hloc",
        metadata={"images_dir": str(root), "intrinsics": source},
    )
