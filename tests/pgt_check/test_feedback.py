"""Feedback while running: progress lines without a TTY, report panels kept from the main pass
(no second measurement), and the last line naming report.html."""

from __future__ import annotations

import json

from pgt_check import runner
from pgt_check.cli import main
from pgt_check.measure import FrameChecker
from pgt_check.output_layout import OUTPUTS
from pgt_check.report.assets import asset_stem


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
               "--out", str(out), "-q", "--enhance", "never", "--separation-frames", "0"])
    assert rc in (0, 1)
    summary = json.loads((out / "summary.json").read_text())
    # each frame measured once: the panels come from the main pass (the separation check's
    # moved copies, off here, are other measurements by design)
    assert len(calls) == summary["n_frames"] == len(set(calls))
    last = capsys.readouterr().out.strip().splitlines()[-1]
    assert last.startswith("pgt-check: report: ") and str(out / "report.html") in last
    index = json.loads((out / OUTPUTS.assets_index).read_text())["frames"]
    assert index and all("arrows_raw" in kinds and "diff" in kinds for kinds in index.values())
    # panels of frames not shown are removed; the shown ones are all there
    folder = out / OUTPUTS.panels_dir
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
          "--out", str(out), "-q", "--enhance", "never", "--report-details", "3",
          "--separation-frames", "0"])
    index = json.loads((out / OUTPUTS.assets_index).read_text())["frames"]
    n = json.loads((out / "summary.json").read_text())["n_frames"]
    assert len(index) == 3 and len(calls) == n + 3
