"""Readers for trajectory formats and images; each converts to the internal Trajectory model.

Every reader returns world_from_cam poses (4x4 float64, OpenCV axes) and cameras in the OpenCV
pixel convention (top-left pixel centre at (0, 0)). Importing this package needs only numpy:
pycolmap, OpenCV and Pillow are imported by the functions that use them.
"""

from __future__ import annotations

from pgt_check.io._text import check_frame_ids
from pgt_check.io.camera import parse_camera_spec
from pgt_check.io.formats import FORMATS, detect_format, read_trajectory
from pgt_check.io.images import image_size, load_image
from pgt_check.io.lamar_write import write_lamar

__all__ = [
    "FORMATS",
    "check_frame_ids",
    "detect_format",
    "image_size",
    "load_image",
    "parse_camera_spec",
    "read_trajectory",
    "write_lamar",
]
