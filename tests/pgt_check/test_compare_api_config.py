"""pgt-check compare, the Python API, --config replay and --print-config."""

from __future__ import annotations

import csv
import json

import pytest

from pgt_check.cli import main
from pgt_check.io import read_trajectory, write_lamar
from pgt_check.types import Trajectory
from pgt_eval import perturb_trajectory


def test_print_config_and_replay_from_config_json(tmp_path, sample_scene, capsys):
    traj, mesh = str(sample_scene / "trajectories.txt"), str(sample_scene / "mesh.glb")
    assert main([traj, "--mesh", mesh, "--threshold-px", "7", "--print-config"]) == 0
    cfg = json.loads(capsys.readouterr().out)
    assert cfg["verdict"]["threshold_px"] == 7.0 and cfg["input"]["mesh"] == mesh
    out = tmp_path / "a"
    assert main([traj, "--mesh", mesh, "--out", str(out), "--limit", "2", "--enhance", "never",
                 "--report-details", "0", "-q"]) == 0
    # the run's own config.json alone replays it (trajectory and mesh come from it)
    out2 = tmp_path / "b"
    assert main(["--config", str(out / "config.json"), "--out", str(out2), "-q"]) == 0
    a = list(csv.DictReader(open(out / "frames.csv")))
    b = list(csv.DictReader(open(out2 / "frames.csv")))
    assert [r["frame_id"] for r in a] == [r["frame_id"] for r in b] == ["0/cam0", "1/cam0"]
    assert [r["corner_error_px"] for r in a] == [r["corner_error_px"] for r in b]
    capsys.readouterr()
    assert main(["--config", str(out / "config.json"), "--print-config"]) == 0
    assert json.loads(capsys.readouterr().out)["limit"] == 2
    assert main(["--out", str(tmp_path / "c")]) == 2  # no trajectory anywhere: input error


def test_api_check_in_memory_trajectory(tmp_path, sample_scene):
    from pgt_check.api import check

    traj = read_trajectory(sample_scene / "trajectories.txt")
    mem = Trajectory(traj.frames[2:5], format="")  # frames 2, 3 (3.5 deg error), 4
    df = check(mem, sample_scene / "mesh.glb", out=str(tmp_path / "o"), report_details=0,
               enhance={"mode": "never"})
    assert list(df["frame_id"]) == ["2/cam0", "3/cam0", "4/cam0"]
    assert list(df["verdict"]) == ["PASS", "FAIL", "PASS"]
    assert abs(df.loc[1, "corr_drot_deg"] - 3.5) < 0.1
    assert df.attrs["summary"]["counts"]["FAIL"] == 1
    assert df.attrs["out"] == str(tmp_path / "o")
    csv_ids = [r["frame_id"] for r in csv.DictReader(open(tmp_path / "o" / "frames.csv"))]
    assert csv_ids == list(df["frame_id"])


def test_api_path_input_and_errors(tmp_path, sample_scene):
    from pgt_check.api import check
    from pgt_check.errors import InputError

    df = check(sample_scene / "trajectories.txt", sample_scene / "mesh.glb", limit=1,
               report_details=0, enhance={"mode": "never"}, correct={"frames": "none"})
    assert len(df) == 1 and df.loc[0, "verdict"] == "PASS"
    with pytest.raises(InputError):
        check(sample_scene / "trajectories.txt", tmp_path / "missing.ply")


def _two_sources(tmp_path, sample_scene):
    a = read_trajectory(sample_scene / "trajectories.txt")
    first = Trajectory(a.frames[:4], a.source, a.format, dict(a.metadata))
    b, injected = perturb_trajectory(first, 0.5, (2.0, 2.0), (0.0, 0.0), seed=0)
    paths = write_lamar(b, tmp_path / "b", suffix="_b")
    return a, b, injected, paths


def test_compare_without_mesh_reports_the_differences(tmp_path, sample_scene, capsys):
    a, b, injected, paths = _two_sources(tmp_path, sample_scene)
    rc = main(["compare", str(sample_scene / "trajectories.txt"), str(paths["trajectories"]),
               "--out", str(tmp_path / "c"), "-q"])
    assert rc == 0
    rows = {r["frame_id"]: r for r in csv.DictReader(open(tmp_path / "c" / "compare.csv"))}
    # write_lamar numbers frames by timestamp 0..3: the ids pair with the sample's
    assert len(rows) == 4
    moved = {p.frame_id for p in injected}
    for fid, r in rows.items():
        if fid in moved:
            assert abs(float(r["drot_deg"]) - 2.0) < 1e-6 and float(r["shift_px"]) > 5
        else:
            assert float(r["drot_deg"]) < 1e-6 and float(r["shift_px"]) < 1e-6
    assert "4 frames in both sources" in capsys.readouterr().out


def test_compare_with_mesh_finds_the_supported_source(tmp_path, sample_scene):
    _, _, injected, paths = _two_sources(tmp_path, sample_scene)
    rc = main(["compare", str(sample_scene / "trajectories.txt"), str(paths["trajectories"]),
               "--mesh", str(sample_scene / "mesh.glb"), "--enhance", "never",
               "--out", str(tmp_path / "c"), "-q"])
    assert rc == 0
    rows = {r["frame_id"]: r for r in csv.DictReader(open(tmp_path / "c" / "compare.csv"))}
    moved = {p.frame_id for p in injected}
    # frame 3 is wrong in A (perturbed.txt); the others: the injected 2 deg make B wrong
    for fid, r in rows.items():
        if fid in moved and fid != "3/cam0":
            assert r["supported"] == "a", r
    summary = json.loads((tmp_path / "c" / "compare.json").read_text())
    assert sum(summary["supported"].values()) == 4


def test_compare_input_error_exits_two(tmp_path, sample_scene, capsys):
    rc = main(["compare", str(sample_scene / "trajectories.txt"), str(tmp_path / "nope.txt")])
    assert rc == 2 and "error" in capsys.readouterr().err


@pytest.mark.slow
@pytest.mark.shared_data
def test_real_data_compare_castle(shared_data, tmp_path):
    d = shared_data / "sceaux_castle"
    rc = main(["compare", str(d / "trajectories.txt"), str(d / "trajectories_colmap.txt"),
               "--sensors-a", str(d / "sensors.txt"), "--sensors-b",
               str(d / "sensors_colmap.txt"), "--out", str(tmp_path), "-q"])
    assert rc == 0
    s = json.loads((tmp_path / "compare.json").read_text())
    # README: rotation differs by a near-constant 1.41 deg, centres by ~0.005 units
    assert s["n_frames"] == 10 and abs(s["drot_deg"]["median"] - 1.41) < 0.02
    assert s["dt"]["median"] < 0.01
