"""Report on the real 7-Scenes redkitchen frames (real ids, paths and photos).

Synthetic measurements on real frame ids, paths and photos: exercises the report on the
dataset's names and images with controlled verdicts. Real runs are in test_real_runs.py.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest
from report_testdata import check_report, judged, read_csv, shared_data_dir, validate

from pgt_check.config import RunConfig
from pgt_check.measure import FrameImages
from pgt_check.report.assets import PANEL_MAX, select_detail_frames, write_frame_assets
from pgt_check.report.junit import junit_xml_text
from pgt_check.report.outputs import write_outputs

pytestmark = pytest.mark.shared_data

DATASET = "7scenes_redkitchen"


def _dataset() -> Path:
    root = shared_data_dir() / DATASET
    if not (root / "images.txt").is_file():
        pytest.skip(f"shared data not found at {root} (set PGT_SHARED_DATA)")
    return root


def _rows(path: Path) -> list[list[str]]:
    out = []
    for line in path.read_text().splitlines():
        if line.strip() and not line.startswith("#"):
            out.append([x.strip() for x in line.split(",")])
    return out


def redkitchen_records(root: Path) -> list[dict]:
    poses = {r[0]: [float(x) for x in r[6:9]] for r in _rows(root / "trajectories.txt")}
    rng = np.random.default_rng(7)
    records = []
    for ts, _sensor, image_path in _rows(root / "images.txt"):
        err = float(rng.lognormal(1.2, 0.7))
        n_matches = int(rng.integers(50, 500))
        n_inl = int(n_matches * rng.uniform(0.2, 0.9))
        records.append(
            {
                "frame_id": ts,
                "timestamp": int(ts),
                "image_path": image_path,
                "width": 640,
                "height": 480,
                "error": "",
                "error_detail": "",
                "coverage": float(rng.uniform(0.5, 1)),
                "shading": "vertex",
                "n_kpts_render": None,
                "n_kpts_photo": None,
                "n_matches": n_matches,
                "n_inliers": n_inl,
                "inlier_ratio": n_inl / n_matches,
                "homography_reason": "",
                "corner_error_px": err,
                "shift_dx_px": float(rng.normal()),
                "shift_dy_px": float(rng.normal()),
                "zoom": 1.0,
                "photo_from_render": None,
                "match_width": 640,
                "match_height": 480,
                "t_load_s": 0.01,
                "t_render_s": 0.01,
                "t_match_s": 0.1,
                "t_homography_s": 0.002,
                "time_s": 0.13,
                "center": poses.get(ts, [0.0, 0.0, 0.0]),
            }
        )
    return records


def test_report_on_redkitchen_frames(tmp_path):
    root = _dataset()
    config = RunConfig.from_dict(
        {"input": {"trajectory": str(root / "trajectories.txt"), "mesh": str(root / "mesh.ply")}}
    )
    records = judged(redkitchen_records(root), config)
    assert len(records) == 100
    assets = {}
    by_id = {r["frame_id"]: r for r in records}
    for fid in select_detail_frames(records, n_worst=5, max_details=12):
        rec = by_id[fid]
        bgr = cv2.imread(str(root / rec["image_path"]))
        assert bgr is not None, rec["image_path"]
        photo = bgr[:, :, ::-1].astype(np.float32) / 255.0
        render = np.roll(photo, 8, axis=1) * 0.8  # stand-in for the renderer
        gray = cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY)
        pts = cv2.goodFeaturesToTrack(gray, 150, 0.01, 8).reshape(-1, 2).astype(np.float64)
        images = FrameImages(
            photo=photo,
            render=render,
            kpts_render=pts + [8, 0],
            kpts_photo=pts,
            inliers=np.arange(len(pts)) % 4 != 0,
        )
        assets[fid] = write_frame_assets(tmp_path, rec, images)
    write_outputs(tmp_path, records, config, assets=assets)
    data = check_report(tmp_path, records)
    assert set(data["assets"]) == set(assets)
    thumb = cv2.imread(str(tmp_path / next(iter(assets.values()))["photo"]))
    assert max(thumb.shape[:2]) <= PANEL_MAX
    # the dataset's relative image paths are shown as written; no path of this machine
    html = (tmp_path / "report.html").read_text(encoding="utf-8")
    assert str(root) not in html and str(tmp_path) not in html
    assert [r["image_path"] for r in read_csv(tmp_path / "frames.csv")][
        0
    ] == "images/frame-000000.color.jpg"
    validate(junit_xml_text(records, {"counts": {}, "gate": {}}))
    validate((tmp_path / "junit.xml").read_text(encoding="utf-8"))
