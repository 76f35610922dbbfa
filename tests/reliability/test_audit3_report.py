"""Third audit (#39), ``pgt-check report OUT`` after an input changed: run.json keeps the
content hashes of every input file the measurements read; ``report`` checks those it can
still read, names the ones that changed and fails the gate unless ``--rejudge-stale`` asks to
judge the stored measurements as they are."""

from __future__ import annotations

import json

from tests.reliability.test_audit3_api import move_mesh


def test_report_after_the_mesh_moved_fails_closed(scene, tmp_path, cli, base_args, case):
    out = tmp_path / "out"
    assert cli(*base_args("--limit", "3", out=out))[0] == 0
    files = json.loads((out / "run.json").read_text())["input_files"]
    assert str(scene / "mesh.glb") in files and str(scene / "trajectories.txt") in files
    move_mesh(scene / "mesh.glb", 0.3)  # a new run fails every frame
    rc, stdout, err = cli("report", out)
    summary = json.loads((out / "summary.json").read_text())
    case("report OUT after the mesh moved 0.3 m", "1, names mesh.glb and --rejudge-stale",
         f"{rc}: {err.strip().splitlines()[-1][:150]}")
    assert rc == 1 and "mesh.glb" in err and "--rejudge-stale" in err
    assert summary["gate"]["passed"] is False and "mesh.glb" in summary["gate"]["explanation"]
    assert summary["inputs_changed"]["rejudged"] is False
    assert "gate FAILED" in stdout
    rc, stdout, err = cli("report", out, "--rejudge-stale")
    summary = json.loads((out / "summary.json").read_text())
    assert rc == 0 and "mesh.glb" in err and summary["gate"]["passed"] is True
    assert summary["inputs_changed"]["rejudged"] is True


def test_report_names_a_changed_photo_and_notes_a_missing_one(scene, tmp_path, cli, base_args):
    out = tmp_path / "out"
    assert cli(*base_args(out=out))[0] == 0
    photo = scene / "images" / "frame-000001.jpg"
    photo.write_bytes(photo.read_bytes() + b"\0")
    (scene / "sensors.txt").rename(scene / "sensors.moved")
    rc, _, err = cli("report", out)
    assert rc == 1 and "frame-000001.jpg" in err and "cannot be read any more" in err
    (scene / "sensors.moved").rename(scene / "sensors.txt")
    photo.write_bytes(photo.read_bytes()[:-1])  # as measured again
    rc, _, err = cli("report", out)
    assert rc == 0 and "changed" not in err
    assert "inputs_changed" not in json.loads((out / "summary.json").read_text())
