from __future__ import annotations

import json

import cv2
import numpy as np
import pytest
from report_testdata import HOSTILE_NAME

from pgt_check.report.assets import (
    THUMB_MAX,
    asset_stem,
    checkerboard,
    draw_matches,
    existing_assets,
    load_assets_index,
    select_detail_frames,
    write_assets_index,
    write_frame_assets,
)
from pgt_check.measure import FrameImages


def rec(fid: str, verdict: str, err: float | None) -> dict:
    return {"frame_id": fid, "verdict": verdict, "corner_error_px": err}


def test_select_detail_frames_order_and_caps():
    records = [
        rec("p1", "PASS", 1.0),
        rec("f1", "FAIL", 30.0),
        rec("u1", "UNVERIFIABLE", None),
        rec("p2", "PASS", 9.0),
        rec("f2", "FAIL", 80.0),
        rec("p3", "PASS", 5.0),
        rec("u2", "UNVERIFIABLE", None),
    ]
    assert select_detail_frames(records) == ["f2", "f1", "u1", "u2", "p2", "p3", "p1"]
    assert select_detail_frames(records, n_worst=1) == ["f2", "f1", "u1", "u2", "p2"]
    assert select_detail_frames(records, max_details=3) == ["f2", "f1", "u1"]
    assert select_detail_frames(records, n_worst=0, max_details=10) == ["f2", "f1", "u1", "u2"]
    assert select_detail_frames(records, max_details=0) == []
    assert select_detail_frames([]) == []


def _images(h: int = 600, w: int = 800, n: int = 300, enhanced: bool = True) -> FrameImages:
    rng = np.random.default_rng(0)
    photo = rng.uniform(0, 1, (h, w, 3)).astype(np.float32)
    render = np.roll(photo, 5, axis=1)
    k0 = rng.uniform(0, [w, h], (n, 2))
    return FrameImages(
        photo=photo,
        render=render,
        enhanced=render * 0.9 if enhanced else None,
        kpts_render=k0,
        kpts_photo=k0 + [5, 0],
        inliers=rng.uniform(size=n) < 0.7,
    )


def test_write_frame_assets_thumbnails(tmp_path):
    record = {"frame_id": HOSTILE_NAME, "image_path": HOSTILE_NAME}
    paths = write_frame_assets(tmp_path, record, _images())
    assert set(paths) == {"render", "enhanced", "photo", "blend", "checker", "matches"}
    stem = asset_stem(HOSTILE_NAME)
    for kind, rel in paths.items():
        assert rel == f"assets/frames/{stem}_{kind}.jpg"
        assert "<" not in rel and "img" not in rel.split("/")[-1].split("_")[0]
        img = cv2.imread(str(tmp_path / rel))
        assert img is not None, rel
        if kind == "matches":
            assert max(img.shape[:2]) <= 2 * THUMB_MAX
        else:
            assert max(img.shape[:2]) <= THUMB_MAX
        assert (tmp_path / rel).stat().st_size < 200_000


def test_write_frame_assets_partial_images(tmp_path):
    only_photo = FrameImages(photo=np.zeros((100, 120, 3), np.float32))
    assert set(write_frame_assets(tmp_path, {"frame_id": "a"}, only_photo)) == {"photo"}
    no_matches = _images(enhanced=False)
    no_matches.kpts_render = no_matches.kpts_photo = no_matches.inliers = None
    paths = write_frame_assets(tmp_path, {"frame_id": "b"}, no_matches)
    assert set(paths) == {"render", "photo", "blend", "checker", "matches"}
    assert write_frame_assets(tmp_path, {"frame_id": "c"}, FrameImages()) == {}


def test_asset_stem_is_stable_and_distinct():
    assert asset_stem("a") == asset_stem("a") != asset_stem("b")
    assert asset_stem("../../etc/passwd").isalnum()


def test_draw_matches_caps_and_colours():
    left = np.zeros((50, 60, 3), np.uint8)
    right = np.zeros((50, 60, 3), np.uint8)
    k = np.array([[10.0, 10.0], [30.0, 40.0]])
    out = draw_matches(left, right, k, k, np.array([True, False]))
    assert out.shape == (50, 120, 3)
    green = (out[:, :, 1] > 150) & (out[:, :, 2] < 120)
    red = (out[:, :, 2] > 150) & (out[:, :, 1] < 120)
    assert green.any() and red.any()
    many = np.random.default_rng(1).uniform(0, 50, (5000, 2))
    draw_matches(left, right, many, many, None, max_drawn=50)  # fast and bounded


def test_checkerboard_alternates():
    a = np.zeros((16, 16, 3), np.uint8)
    b = np.full((16, 16, 3), 255, np.uint8)
    c = checkerboard(a, b, n_tiles=2)
    assert c[0, 0, 0] == 0 and c[0, 15, 0] == 255 and c[15, 15, 0] == 0


def test_index_roundtrip_drops_missing_and_unsafe(tmp_path):
    paths = write_frame_assets(tmp_path, {"frame_id": "f1"}, _images())
    assets = {
        "f1": paths,
        "f2": {"photo": "assets/frames/missing.jpg"},
        "f3": {"photo": "../outside.jpg", "render": "/etc/passwd"},
    }
    (tmp_path / "outside.jpg").write_bytes(b"x")
    write_assets_index(tmp_path, assets)
    assert json.loads((tmp_path / "assets" / "index.json").read_text())["version"] == 1
    assert load_assets_index(tmp_path) == {"f1": paths}
    assert existing_assets(tmp_path, None) == {}
    assert load_assets_index(tmp_path / "nowhere") == {}


@pytest.mark.parametrize("bad", ["not json", "[1, 2]"])
def test_broken_index_is_ignored(tmp_path, bad):
    (tmp_path / "assets").mkdir()
    (tmp_path / "assets" / "index.json").write_text(bad)
    assert load_assets_index(tmp_path) == {}
