"""Feedback while running: progress lines without a TTY, report panels kept from the main pass
(no second measurement), and the last line naming report.html."""

from __future__ import annotations

import json
import logging

from pgt_check import runner
from pgt_check.cli import main
from pgt_check.measure import FrameChecker
from pgt_check.report.assets import ASSETS_DIR, FRAMES_SUBDIR, asset_stem


def test_log_progress_every_interval_and_at_the_end(caplog):
    t = iter([0.0, 1.0, 2.0, 6.0, 7.0, 12.5])
    with caplog.at_level(logging.INFO, logger="pgt_check.runner"):
        got = list(runner.log_progress(range(5), 5, "pgt-check", interval_s=5.0,
                                       clock=lambda: next(t)))
    assert got == [0, 1, 2, 3, 4]
    lines = [r.getMessage() for r in caplog.records]
    # clock: start 0; items done at 1, 2, 6 (a line), 7, 12.5 (a line, the last: no repeat)
    assert len(lines) == 2, lines
    assert lines[0] == "pgt-check: 3/5 frames (60 %), 0.50 frames/s, about 4 s left"
    assert lines[1] == "pgt-check: 5/5 frames (100 %), 0.40 frames/s"
    caplog.clear()
    t2 = iter([0.0, 1.0, 1.5, 2.0])  # fast: no line in between, one at the end
    with caplog.at_level(logging.INFO, logger="pgt_check.runner"):
        list(runner.log_progress("ab", 2, "x", interval_s=5.0, clock=lambda: next(t2)))
    assert [r.getMessage() for r in caplog.records] == ["x: 2/2 frames (100 %), 1.00 frames/s"]
    assert list(runner.log_progress([], 0, "x", clock=lambda: 0.0)) == []


def _count_measures(monkeypatch) -> list[str]:
    """The frame ids ``FrameChecker.measure`` is called with, in order (filled as it runs)."""
    calls: list[str] = []
    measure = FrameChecker.measure

    def counting(self, frame, keep=None):
        calls.append(frame.frame_id)
        return measure(self, frame, keep)

    monkeypatch.setattr(FrameChecker, "measure", counting)
    return calls


def test_sample_run_keeps_panels_from_the_main_pass(tmp_path, capsys, sample_scene, monkeypatch):
    calls = _count_measures(monkeypatch)
    out = tmp_path / "out"
    rc = main([str(sample_scene / "trajectories.txt"), "--mesh", str(sample_scene / "mesh.glb"),
               "--out", str(out), "-q", "--enhance", "never"])
    assert rc in (0, 1)
    summary = json.loads((out / "summary.json").read_text())
    assert len(calls) == summary["n_frames"] == len(set(calls))  # each frame measured once
    last = capsys.readouterr().out.strip().splitlines()[-1]
    assert last.startswith("pgt-check: report: ") and str(out / "report.html") in last
    index = json.loads((out / ASSETS_DIR / "index.json").read_text())["frames"]
    assert index and all("arrows_raw" in kinds and "diff" in kinds for kinds in index.values())
    # panels of frames not shown are removed; the shown ones are all there
    folder = out / ASSETS_DIR / FRAMES_SUBDIR
    stems = {p.name.split("_")[0].split(".")[0] for p in folder.iterdir()}
    assert stems == {asset_stem(f) for f in index}
    for kinds in index.values():
        assert all((out / rel).is_file() for rel in kinds.values())
    assert "raw_vs_enhanced" in summary


def test_missing_panels_are_measured_again(tmp_path, sample_scene, monkeypatch):
    """Frames without main-pass panels (here: a sink that writes none) are measured again."""
    monkeypatch.setattr(runner, "panel_writer", lambda config, fingerprint: None)
    calls = _count_measures(monkeypatch)
    out = tmp_path / "out"
    main([str(sample_scene / "trajectories.txt"), "--mesh", str(sample_scene / "mesh.glb"),
          "--out", str(out), "-q", "--enhance", "never", "--report-details", "3"])
    index = json.loads((out / ASSETS_DIR / "index.json").read_text())["frames"]
    n = json.loads((out / "summary.json").read_text())["n_frames"]
    assert len(index) == 3 and len(calls) == n + 3
