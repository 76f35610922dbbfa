"""Classes 5 and 6: distinct per-frame reasons (image size mismatch, reference unreadable, pixel
cap exceeded) and a pixel cap checked on the header, before decoding."""

from __future__ import annotations

import json
import struct
import zlib

import numpy as np
import pytest

from pgt_check.errors import PixelCapError
from pgt_check.io.images import load_image


def _png_header_only(path, width, height):
    """A tiny PNG that declares width x height (a decompression bomb's header)."""
    def chunk(kind, data):
        return struct.pack(">I", len(data)) + kind + data + struct.pack(
            ">I", zlib.crc32(kind + data) & 0xFFFFFFFF)

    ihdr = struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr)
                     + chunk(b"IDAT", zlib.compress(b"\0" * 64)) + chunk(b"IEND", b""))
    return path


def _reasons(out):
    return json.loads((out / "summary.json").read_text())["statistics"]["unverifiable_reasons"]


def test_pixel_cap_on_header(tmp_path, case):
    bomb = _png_header_only(tmp_path / "bomb.png", 20000, 15000)
    assert bomb.stat().st_size < 1000
    with pytest.raises(PixelCapError, match="300000000 pixels"):
        load_image(bomb)  # default cap 100 MP: refused without decoding
    case("PNG declaring 20000x15000 (< 1 KB file)", "pixel_cap_exceeded, no decode",
         "PixelCapError before decoding")


def test_pixel_cap_option_gives_reason(cli, base_args, tmp_path, case):
    rc, _, _ = cli(*base_args("--max-image-pixels", "1000"))
    reasons = _reasons(tmp_path / "out")
    case("--max-image-pixels 1000 on 320x240 photos", "1, pixel_cap_exceeded",
         f"{rc}: {reasons}")
    assert rc == 1 and reasons == {"pixel_cap_exceeded": 2}


def test_photo_of_other_size_is_size_mismatch(scene, cli, base_args, tmp_path, case):
    import cv2

    cv2.imwrite(str(scene / "images" / "frame-000000.jpg"), np.zeros((100, 100, 3), np.uint8))
    rc, _, _ = cli(*base_args("--enhance", "never"))
    reasons = _reasons(tmp_path / "out")
    case("photo 100x100 for a 320x240 camera", "image_size_mismatch (not image_unreadable)",
         f"{rc}: {reasons}")
    assert reasons == {"image_size_mismatch": 1}


def test_unreadable_reference_has_its_own_reason(scene, cli, base_args, tmp_path, case):
    for p in sorted((scene / "images").glob("*.jpg"))[1:]:
        p.write_bytes(b"not a jpeg")  # every possible reference of frame 0 is corrupt
    rc, _, _ = cli(*base_args("--enhance", "always", "--limit", "1"))
    reasons = _reasons(tmp_path / "out")
    case("all reference photos corrupt (--enhance always)", "reference_unreadable",
         f"{rc}: {reasons}")
    assert rc == 1 and reasons == {"reference_unreadable": 1}
