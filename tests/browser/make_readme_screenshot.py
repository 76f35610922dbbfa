"""Regenerate reports/report_screenshot.png (not a test): a report of the 7-Scenes redkitchen
frames (real ids, paths and photos; synthetic measurements and a shifted photo as stand-in
render until the pipeline is wired), shot in headless Chromium and cropped to summary + plots,
the first detail panel and the top of the frame table.

    PYTHONPATH=. python tests/browser/make_readme_screenshot.py [OUT.png]
"""

from __future__ import annotations

import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import cv2
import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent / "pgt_check" / "report"))

from report_testdata import judged, shared_data_dir  # noqa: E402
from test_shared_data import redkitchen_records  # noqa: E402

from pgt_check.config import RunConfig  # noqa: E402
from pgt_check.measure import FrameImages  # noqa: E402
from pgt_check.report.assets import select_detail_frames, write_frame_assets  # noqa: E402
from pgt_check.report.outputs import write_outputs  # noqa: E402


def build(out: Path) -> None:
    root = shared_data_dir() / "7scenes_redkitchen"
    config = RunConfig.from_dict(
        {"input": {"trajectory": str(root / "trajectories.txt"), "mesh": str(root / "mesh.ply")}}
    )
    records = judged(redkitchen_records(root), config)
    by_id = {r["frame_id"]: r for r in records}
    assets = {}
    for fid in select_detail_frames(records, n_worst=5, max_details=20):
        bgr = cv2.imread(str(root / by_id[fid]["image_path"]))
        photo = bgr[:, :, ::-1].astype(np.float32) / 255.0
        render = cv2.warpAffine(photo, np.float32([[1, 0, 12], [0, 1, 6]]), (640, 480)) * 0.85
        gray = cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY)
        pts = cv2.goodFeaturesToTrack(gray, 120, 0.01, 8).reshape(-1, 2).astype(np.float64)
        images = FrameImages(
            photo=photo,
            render=render,
            kpts_render=pts + [12, 6],
            kpts_photo=pts,
            inliers=np.arange(len(pts)) % 5 != 0,
        )
        assets[fid] = write_frame_assets(out, by_id[fid], images)
    write_outputs(out, records, config, assets=assets)


def main(dest: str = "reports/report_screenshot.png") -> None:
    from PIL import Image

    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "run"
        build(out)
        shot = Path(tmp) / "full.png"
        subprocess.run(
            [
                shutil.which("chromium") or "chromium",
                "--headless",
                "--no-sandbox",
                "--disable-gpu",
                "--hide-scrollbars",
                f"--user-data-dir={tmp}/profile",
                "--virtual-time-budget=5000",
                "--window-size=1280,3400",
                f"--screenshot={shot}",
                (out / "report.html").as_uri(),
            ],
            check=True,
            capture_output=True,
        )
        im = cv2.imread(str(shot))
    # section headings have a full-width 1 px #e0e0e0 rule: Plots, Frames to inspect, All frames
    rule = (np.abs(im.astype(int) - 224).sum(axis=2) < 6).sum(axis=1) > 1100
    ys = [int(y) for y in np.flatnonzero(rule)]
    inspect_y = next(y for y in ys if y > 1000)
    table_y = ys[-1]
    first_panel_end = next(y for y in ys if y > inspect_y + 280)
    parts = [
        im[: inspect_y - 38],
        im[inspect_y - 38 : first_panel_end + 4],
        im[table_y - 38 : table_y + 380],
    ]
    sep = np.full((6, im.shape[1], 3), 255, np.uint8)
    comp = np.vstack([parts[0], sep, parts[1], sep, parts[2]])
    comp = cv2.resize(
        comp, (960, round(comp.shape[0] * 960 / comp.shape[1])), interpolation=cv2.INTER_AREA
    )
    pil = Image.fromarray(comp[:, :, ::-1]).quantize(colors=256, dither=Image.Dither.NONE)
    pil.save(dest, optimize=True)
    print(f"wrote {dest} ({Path(dest).stat().st_size // 1024} KiB)")


if __name__ == "__main__":
    main(*sys.argv[1:])
