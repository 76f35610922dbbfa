from __future__ import annotations

import pytest

from pgt_check.errors import InputError
from pgt_check.io import parse_camera_spec
from pgt_check.types import Camera


def test_pinhole_spec_half_pixel() -> None:
    """The spec is in COLMAP convention: cx=320 means the OpenCV principal point 319.5."""
    cam = parse_camera_spec("PINHOLE,640,480,525,526,320,240")
    assert cam == Camera.pinhole(640, 480, 525.0, 526.0, 319.5, 239.5)
    assert cam.to_colmap_params() == (525.0, 526.0, 320.0, 240.0)


@pytest.mark.parametrize(
    ("spec", "expected"),
    [
        ("simple_pinhole 64 48 50 32 24", Camera("SIMPLE_PINHOLE", 64, 48, (50.0, 31.5, 23.5))),
        (
            "OPENCV, 64, 48, 50, 51, 32, 24, 0.1, 0.01, 0.001, 0.002",
            Camera("OPENCV", 64, 48, (50, 51, 31.5, 23.5, 0.1, 0.01, 0.001, 0.002)),
        ),
    ],
)
def test_other_models_and_separators(spec: str, expected: Camera) -> None:
    assert parse_camera_spec(spec) == expected


@pytest.mark.parametrize(
    ("spec", "fragment"),
    [
        ("", "empty"),
        ("FISHEYE,64,48,1,2,3", "expected a model"),
        ("PINHOLE,640,480,525,525,320", "expected 7 fields"),
        ("PINHOLE,640,480,525,525,320,x", "numeric"),
        ("PINHOLE,640.5,480,525,525,320,240", "integer"),
        ("PINHOLE,640,480,-525,525,320,240", "focal"),
        ("PINHOLE,0,480,525,525,320,240", "positive"),
    ],
)
def test_bad_specs(spec: str, fragment: str) -> None:
    with pytest.raises(InputError, match=fragment):
        parse_camera_spec(spec)
