from __future__ import annotations

import json

import cv2
import numpy as np
import pytest
from report_testdata import HOSTILE_NAME

from pgt_check.config import RunConfig
from pgt_check.measure.paths import FrameImages, PathImages
from pgt_check.report.assets import (
    PANEL_MAX,
    TILE_MAX,
    PanelWriter,
    arrow_magnification,
    asset_stem,
    checkerboard,
    difference_image,
    draw_arrows,
    existing_assets,
    grid_points,
    homography_displacements,
    load_assets_index,
    main_pass_assets,
    manifest_path,
    prune_panels,
    select_detail_frames,
    write_assets_index,
    write_frame_assets,
)


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


def _shift_h(dx: float, dy: float) -> np.ndarray:
    return np.array([[1.0, 0, dx], [0, 1.0, dy], [0, 0, 1.0]])


def _images(h: int = 600, w: int = 800, n: int = 300, enhanced: bool = True) -> FrameImages:
    rng = np.random.default_rng(0)
    photo = rng.uniform(0, 1, (h, w, 3)).astype(np.float32)
    render = np.roll(photo, 5, axis=1)
    k0 = rng.uniform(0, [w, h], (n, 2))
    inl = rng.uniform(size=n) < 0.7
    paths = {"raw": PathImages(k0, k0 + [5, 0], inl, _shift_h(5, 0))}
    if enhanced:
        paths["enhanced"] = PathImages(k0, k0 + [4, 1], inl, _shift_h(4, 1))
    return FrameImages(
        photo=photo,
        render=render,
        enhanced=render * 0.9 if enhanced else None,
        kpts_render=k0,
        kpts_photo=k0 + [5, 0],
        inliers=inl,
        paths=paths,
    )


def test_write_frame_assets_panels(tmp_path):
    record = {"frame_id": HOSTILE_NAME, "image_path": HOSTILE_NAME}
    paths = write_frame_assets(tmp_path, record, _images())
    assert set(paths) == {"render", "enhanced", "photo", "diff", "blend", "checker",
                          "arrows_raw", "arrows_enhanced"}
    stem = asset_stem(HOSTILE_NAME)
    for kind, rel in paths.items():
        assert rel == f"assets/frames/{stem}_{kind}.jpg"
        assert "<" not in rel and "img" not in rel.split("/")[-1].split("_")[0]
        img = cv2.imread(str(tmp_path / rel))
        assert img is not None, rel
        if kind == "diff":  # render | photo | difference, 4 px gaps
            assert img.shape[:2] == (TILE_MAX * 600 // 800, 3 * TILE_MAX + 8)
        else:  # full working resolution (below PANEL_MAX)
            assert img.shape[:2] == (600, 800), kind
    # the two arrow panels differ (each path drawn in its own colour and homography)
    a = cv2.imread(str(tmp_path / paths["arrows_raw"])).astype(int)
    b = cv2.imread(str(tmp_path / paths["arrows_enhanced"])).astype(int)
    assert np.abs(a - b).mean() > 1.0


def test_panels_are_capped_at_panel_max(tmp_path):
    big = FrameImages(photo=np.zeros((900, PANEL_MAX + 320, 3), np.float32))
    rel = write_frame_assets(tmp_path, {"frame_id": "big"}, big)["photo"]
    assert max(cv2.imread(str(tmp_path / rel)).shape[:2]) == PANEL_MAX


def test_write_frame_assets_partial_images(tmp_path):
    only_photo = FrameImages(photo=np.zeros((100, 120, 3), np.float32))
    assert set(write_frame_assets(tmp_path, {"frame_id": "a"}, only_photo)) == {"photo"}
    no_matches = _images(enhanced=False)
    no_matches.kpts_render = no_matches.kpts_photo = no_matches.inliers = None
    no_matches.paths = {}
    paths = write_frame_assets(tmp_path, {"frame_id": "b"}, no_matches)
    assert set(paths) == {"render", "photo", "diff", "blend", "checker"}
    # an older checker's images (deciding path only, no homography) still give an arrow panel
    old = _images(enhanced=False)
    old.paths = {}
    assert "arrows_raw" in write_frame_assets(tmp_path, {"frame_id": "d"}, old)
    assert write_frame_assets(tmp_path, {"frame_id": "c"}, FrameImages()) == {}


def test_homography_arrows_follow_the_homography():
    pts = grid_points(640, 480)
    assert pts.shape == (63, 2)
    assert pts[:, 0].min() > 0 and pts[:, 0].max() < 639 and pts[:, 1].max() < 479
    d = homography_displacements(_shift_h(3.0, -2.0), pts)
    assert np.allclose(d, [3.0, -2.0])
    zoom = np.diag([1.1, 1.1, 1.0])
    dz = homography_displacements(zoom, np.array([[0.0, 0.0], [100.0, 50.0]]))
    assert np.allclose(dz, [[0, 0], [10.0, 5.0]])
    assert np.isnan(homography_displacements(np.diag([1.0, 1.0, 0.0]), np.zeros((1, 2)))).all()
    # one factor per frame: the median arrow becomes about 30 px, within [1, 20]
    assert arrow_magnification([d]) == 8  # |d| = 3.6 px
    assert arrow_magnification([np.full((5, 2), 100.0)]) == 1
    assert arrow_magnification([np.zeros((5, 2))]) == 20
    assert arrow_magnification([]) == 20


def test_draw_arrows_marks_matches_and_homography():
    photo = np.full((240, 320, 3), 128, np.uint8)
    k = np.array([[70.0, 140.0], [200.0, 200.0]])  # between the grid's arrows
    path = PathImages(k, k + [1.0, 0.0], np.array([True, False]), _shift_h(2.0, 0.0))
    out = draw_arrows(photo, path, "raw", magnification=5)
    assert out.shape == photo.shape
    b, g, r = out[:, :, 0], out[:, :, 1], out[:, :, 2]
    orange = (r > 200) & (g > 100) & (g < 180) & (b < 60)
    green = (out[:, :, 1] > 150) & (out[:, :, 2] < 120) & (out[:, :, 0] < 120)
    red = (out[:, :, 2] > 150) & (out[:, :, 1] < 100)
    assert orange.sum() > 100 and green.any() and red.any()
    none = draw_arrows(photo, PathImages(k, k, np.array([False, False]), None), "enhanced", 1)
    assert not ((none[:, :, 0] > 200) & (none[:, :, 1] > 150) & (none[:, :, 2] < 80))[30:].any()
    many = np.random.default_rng(1).uniform(0, 100, (5000, 2))
    draw_arrows(photo, PathImages(many, many, np.ones(5000, bool), None), "raw", 3)  # bounded


def test_difference_image_ignores_brightness_and_shows_changes():
    rng = np.random.default_rng(2)
    a = rng.integers(0, 255, (40, 50, 3)).astype(np.uint8)
    brighter = np.clip(a.astype(int) * 0.8 + 30, 0, 255).astype(np.uint8)
    assert difference_image(a, brighter).mean() < 8
    assert difference_image(a, np.roll(a, 7, axis=1)).mean() > 40
    with pytest.raises(ValueError):
        difference_image(a, a[:10])


def _measurement(fid: str, err: float | None, inliers: int = 100):
    from report_testdata import from_flat, synthetic_measurements

    rec = synthetic_measurements(1, hostile=False)[0]
    rec.update(frame_id=fid, corner_error_px=err, n_inliers=inliers,
               homography_reason="" if err is not None else "too_few_matches")
    return from_flat(rec)


def test_panel_writer_keeps_likely_detail_frames(tmp_path):
    config = RunConfig()  # threshold 16 px at 640x480
    w = PanelWriter(tmp_path, "fp1", config.verdict, near=0.5, n_worst=2)
    imgs = _images(120, 160, 40)
    order = [("a", 1.0), ("b", 2.0), ("c", 0.5), ("d", 3.0), ("e", 10.0), ("f", None), ("g", 0.1)]
    wrote = {fid: w(_measurement(fid, err), imgs) is not None for fid, err in order}
    # a, b: first two; c: below both; d: new worst; e: >= 0.5 x threshold; f: no homography
    assert wrote == {"a": True, "b": True, "c": False, "d": True, "e": True, "f": True,
                     "g": False}
    assert w(_measurement("h", 0.2, inliers=3), imgs) is not None  # too few inliers
    assert w(_measurement("i", 5.0), None) is None  # nothing kept: nothing written
    assert json.loads(manifest_path(tmp_path, "d").read_text())["fingerprint"] == "fp1"
    got = main_pass_assets(tmp_path, ["a", "c", "d", "zz"], "fp1")
    assert set(got) == {"a", "d"} and got["d"]["arrows_raw"].endswith("_arrows_raw.jpg")
    assert main_pass_assets(tmp_path, ["a", "d"], "other-settings") == {}
    (tmp_path / got["a"]["photo"]).unlink()  # incomplete panels are measured again
    assert set(main_pass_assets(tmp_path, ["a", "d"], "fp1")) == {"d"}
    n_files = len(list((tmp_path / "assets" / "frames").iterdir()))
    removed = prune_panels(tmp_path, ["d", "e"])
    left = list((tmp_path / "assets" / "frames").iterdir())
    assert removed == n_files - len(left) > 0
    assert {p.name.split("_")[0].split(".")[0] for p in left} == {asset_stem("d"), asset_stem("e")}
    import pickle

    assert pickle.loads(pickle.dumps(w)).fingerprint == "fp1"  # travels to process workers


def test_asset_stem_is_stable_and_distinct():
    assert asset_stem("a") == asset_stem("a") != asset_stem("b")
    assert asset_stem("../../etc/passwd").isalnum()


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
