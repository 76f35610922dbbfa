"""Reports of real pgt-check runs (not synthetic records): the sample scene and 7-Scenes."""

from __future__ import annotations

import json

import pytest
from report_testdata import check_report, validate

from pgt_check.cli import main


def _records(out):
    """The store's current record of each frame, in trajectory order (run.json's frame ids): a
    frame measured again (the reference pass: references whose own evidence passed) has a later
    record in records.jsonl that replaces the first."""
    latest = {}
    for line in (out / "records.jsonl").read_text().splitlines():
        rec = json.loads(line)
        latest[rec["frame_id"]] = rec
    return [latest[fid] for fid in json.loads((out / "run.json").read_text())["frame_ids"]]


def test_report_of_a_sample_data_run(tmp_path, sample_scene):
    out = tmp_path / "out"
    rc = main([str(sample_scene / "trajectories.txt"), "--mesh", str(sample_scene / "mesh.glb"),
               "--out", str(out), "-q", "--report-details", "8"])
    assert rc == 1  # perturbed frames fail the gate
    data = check_report(out, _records(out))
    validate((out / "junit.xml").read_text())
    perturbed = {ln.split(",")[0] for ln in (sample_scene / "perturbed.txt").read_text()
                 .splitlines() if ln and not ln.startswith("#")}
    # every FAIL frame (= the perturbed ones) has an image panel
    assert perturbed <= set(data["assets"])
    assert "/work/" not in (out / "report.html").read_text()  # no absolute machine paths


@pytest.mark.shared_data
def test_report_of_a_real_7scenes_run(tmp_path, shared_data):
    root = shared_data / "7scenes_redkitchen"
    out = tmp_path / "out"
    rc = main([str(root / "trajectories.txt"), "--mesh", str(root / "mesh.ply"), "--out",
               str(out), "-q", "--limit", "6", "--report-details", "3", "--enhance", "always",
               "--enhance-method", "reproject", "--threshold-px", "20"])
    assert rc in (0, 1)
    data = check_report(out, _records(out))
    validate((out / "junit.xml").read_text())
    assert len(data["assets"]) == 3
    assert any(k == "enhanced" for kinds in data["assets"].values() for k in kinds)
