"""Open report.html in headless Chromium: no console errors, table sorts/filters, screenshot.

The page has a self-test hook: ``report.html#selftest`` sorts and filters the table through its
own controls once the page has loaded and writes the results into ``#selftest-result``, which we
read back with ``--dump-dom``. Set ``PGT_REPORT_SCREENSHOT=path.png`` to keep the screenshot.
"""

from __future__ import annotations

import html
import json
import os
import re
import shutil
import subprocess
from pathlib import Path

import cv2
import numpy as np
import pytest
from report_testdata import (  # tests/pgt_check/report is on pythonpath (pyproject)
    HOSTILE_NAME,
    PageParser,
    judged,
    shared_errors_summary,
    synthetic_measurements,
    with_verdict_columns,
)

from pgt_check.config import RunConfig  # noqa: E402
from pgt_check.measure.paths import FrameImages, PathImages  # noqa: E402
from pgt_check.report.assets import select_detail_frames, write_frame_assets  # noqa: E402
from pgt_check.report.outputs import write_outputs  # noqa: E402

pytestmark = pytest.mark.browser

FLAGS = (
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--hide-scrollbars",
    "--enable-logging=stderr",
    "--v=0",
)
#: Chromium log lines that mean the page misbehaved (page console output, CSP refusals)
BAD_LOG = re.compile(r"CONSOLE|Uncaught|Refused to", re.IGNORECASE)


def chromium() -> str:
    for name in (
        os.environ.get("PGT_CHROMIUM", ""),
        "chromium",
        "chromium-browser",
        "google-chrome",
    ):
        if name and shutil.which(name):
            return shutil.which(name)
    pytest.skip("headless chromium not installed (apt-get install chromium; scripts/setup.sh)")


def run_chromium(tmp: Path, *args: str) -> subprocess.CompletedProcess:
    cmd = [chromium(), *FLAGS, f"--user-data-dir={tmp / 'chromium-profile'}", *args]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=120, check=False)


def console_problems(stderr: str) -> list[str]:
    return [line for line in stderr.splitlines() if BAD_LOG.search(line)]


def _images(seed: int) -> FrameImages:
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:240, 0:320]
    base = ((x // 20 + y // 20) % 2).astype(np.float32)
    photo = np.stack([base, 0.5 + 0.5 * np.sin(x / 15.0), y / 240.0], axis=2).astype(np.float32)
    render = np.roll(photo, 3 + seed % 7, axis=1) * 0.9
    k = rng.uniform(0, [320, 240], (120, 2))
    inl = rng.uniform(size=120) < 0.7
    shift = np.array([[1.0, 0, 3], [0, 1.0, 1], [0, 0, 1.0]])
    return FrameImages(
        photo=photo,
        render=render,
        enhanced=render * 0.95,
        kpts_render=k,
        kpts_photo=k + [3, 1],
        inliers=inl,
        paths={"raw": PathImages(k, k + [3, 1], inl, shift),
               "enhanced": PathImages(k, k + [2, 1], inl, shift * [1, 1, 0.7] + [0, 0, 0.3])},
    )


def _records(config=None):
    return with_verdict_columns(judged(synthetic_measurements(250, seed=1, enhanced=True), config))


@pytest.fixture(scope="module")
def report(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("report")
    config = RunConfig.from_dict(
        {"input": {"trajectory": "redkitchen/trajectories.txt", "mesh": "redkitchen/mesh.ply"}}
    )
    records = _records(config)
    by_id = {r["frame_id"]: r for r in records}
    assets = {
        fid: write_frame_assets(out, by_id[fid], _images(i))
        for i, fid in enumerate(select_detail_frames(records, n_worst=10, max_details=60))
    }
    write_outputs(out, records, config, assets=assets,
                  extra={"shared_errors": shared_errors_summary(250)})
    return out


def test_selftest_sorts_and_filters_without_console_errors(report, tmp_path):
    url = (report / "report.html").as_uri() + "#selftest"
    proc = run_chromium(tmp_path, "--virtual-time-budget=5000", "--window-size=1400,1000",
                        "--dump-dom", url)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert console_problems(proc.stderr) == []
    m = re.search(r'<pre id="selftest-result"[^>]*>(.*?)</pre>', proc.stdout, re.S)
    assert m, "self-test did not run"
    result = json.loads(html.unescape(m.group(1)))
    assert result["errors"] == []
    assert result["ok"], result["checks"]
    assert all(result["checks"].values()), result["checks"]
    for name in (
        "sort_asc",
        "sort_desc",
        "filter_verdict",
        "filter_text",
        "page_next",
        "detail_opens",
        "all_columns",
        "lightbox_opens",
        "lightbox_closes",
        "flicker_swaps",
    ):
        assert result["checks"][name], name
    assert result["sorted_desc"] == sorted(result["sorted_desc"], reverse=True)
    n_fail = sum(1 for r in _records() if r["verdict"] == "FAIL")
    assert result["n_fail_shown"] == n_fail
    assert result["n_rows"] == 250
    assert result["n_inspect_panels"] == 6
    # the default columns fit a 1400 px window; "all columns" shows the rest
    assert result["window_width"] == 1400
    assert result["table_overflow_px"] <= 0, result["table_overflow_px"]
    assert result["n_cols_default"] < result["n_cols_all"]
    assert result["n_disagree_rows"] == 50  # with_verdict_columns marks every 5th frame
    assert result["flicker"]


def test_hostile_file_name_renders_as_text(report, tmp_path):
    proc = run_chromium(
        tmp_path, "--virtual-time-budget=5000", "--dump-dom", (report / "report.html").as_uri()
    )
    assert proc.returncode == 0
    assert console_problems(proc.stderr) == []
    page = PageParser()
    page.feed(proc.stdout)
    imgs = [a.get("src") for tag, a in page.tags if tag == "img" and a.get("src")]  # lightbox: none
    assert imgs and all(str(src).startswith("assets/") for src in imgs), imgs
    outside_scripts = re.sub(r"<script\b.*?</script>", "", proc.stdout, flags=re.S)
    escaped = html.escape(HOSTILE_NAME, quote=False)
    assert escaped in outside_scripts  # shown as text in the table
    assert "<img src=x" not in outside_scripts and '<img src="x"' not in outside_scripts
    assert "onerror" not in outside_scripts.replace(escaped, "")


def test_screenshot(report, tmp_path):
    shot = tmp_path / "report.png"
    proc = run_chromium(
        tmp_path,
        "--virtual-time-budget=5000",
        "--window-size=1280,2000",
        f"--screenshot={shot}",
        (report / "report.html").as_uri(),
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert console_problems(proc.stderr) == []
    img = cv2.imread(str(shot))
    assert img is not None and img.shape[1] == 1280
    assert float(img.std()) > 10  # not a blank page
    keep = os.environ.get("PGT_REPORT_SCREENSHOT")
    if keep:
        shutil.copyfile(shot, keep)
