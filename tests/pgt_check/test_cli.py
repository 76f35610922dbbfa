import json
import shutil
import sys

import pytest

from pgt_check.cli import main


def test_help_exits_zero(capsys):
    assert main(["--help"]) == 0
    assert "--mesh" in capsys.readouterr().out


def test_help_lists_every_subcommand_and_each_has_help(capsys):
    from pgt_check.commands import SUBCOMMANDS

    assert set(SUBCOMMANDS) == {"report", "compare", "enhance"}
    assert main(["--help"]) == 0
    out = capsys.readouterr().out
    for name, sub in SUBCOMMANDS.items():
        assert f"pgt-check {name} {sub.usage}" in out
        assert main([name, "--help"]) == 0
        assert capsys.readouterr().out.startswith(f"usage: pgt-check {name} ")
        assert main([name, "--no-such-flag"]) == 2  # one line (see test_audit2_usage)
        assert capsys.readouterr().err.startswith(f"pgt-check {name}: error: ")


def test_usage_error_exits_two(capsys):
    assert main([]) == 2
    assert main(["traj.txt"]) == 2  # --mesh is required


def test_missing_mesh_is_input_error(tmp_path, capsys):
    t = tmp_path / "traj.txt"
    t.write_text("# timestamp tx ty tz qx qy qz qw\n0 0 0 0 0 0 0 1\n")
    assert main([str(t), "--mesh", str(tmp_path / "nope.ply"), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert "mesh not found" in err and "Traceback" not in err


def test_malformed_trajectory_names_file_and_line(tmp_path, capsys, sample_scene):
    t = tmp_path / "trajectories.txt"
    lines = (sample_scene / "trajectories.txt").read_text().splitlines()
    lines[2] = "0, cam0, 1.0, 0, 0"  # too few columns
    t.write_text("\n".join(lines) + "\n")
    for name in ("sensors.txt", "images.txt"):
        shutil.copy(sample_scene / name, tmp_path / name)
    rc = main([str(t), "--mesh", str(sample_scene / "mesh.glb"), "--out", str(tmp_path / "o")])
    err = capsys.readouterr().err
    assert rc == 2
    assert "trajectories.txt:3" in err and "Traceback" not in err


def test_unknown_config_key_is_input_error(tmp_path, capsys, sample_scene):
    cfg = tmp_path / "c.json"
    cfg.write_text(json.dumps({"match": {"max_kpts": 3}}))
    rc = main([str(sample_scene / "trajectories.txt"), "--mesh", str(sample_scene / "mesh.glb"),
               "--config", str(cfg)])
    assert rc == 2
    assert "unknown key 'max_kpts'" in capsys.readouterr().err


def test_sample_run_gate_and_outputs(tmp_path, capsys, sample_scene):
    out = tmp_path / "out"
    rc = main([str(sample_scene / "trajectories.txt"), "--mesh", str(sample_scene / "mesh.glb"),
               "--out", str(out), "-q"])
    summary = json.loads((out / "summary.json").read_text())
    assert rc == (0 if summary["gate"]["passed"] else 1)
    assert rc == 1  # the sample scene has deliberately perturbed frames
    assert (out / "frames.csv").is_file() and (out / "records.jsonl").is_file()
    # a laxer gate passes with the same measurements, via the report subcommand (no recompute)
    n = summary["n_frames"]
    rc2 = main(["report", str(out), "--max-fail-fraction", "1.0"])
    assert rc2 == 0
    assert json.loads((out / "summary.json").read_text())["n_frames"] == n


@pytest.mark.parametrize("enhance", [["--enhance", "never"], ["--enhance", "always"]])
def test_sift_run_without_mariner_does_not_import_torch(tmp_path, sample_scene, enhance):
    """Raw-only and reprojection-enhanced runs with an OpenCV matcher never import torch."""
    import subprocess

    code = (
        "import sys\n"
        "from pgt_check.cli import main\n"
        f"rc = main([{str(sample_scene / 'trajectories.txt')!r}, '--mesh', "
        f"{str(sample_scene / 'mesh.glb')!r}, '--out', {str(tmp_path / 'o')!r}, '-q', "
        f"'--limit', '3', '--report-details', '0', *{enhance!r}])\n"
        "assert rc in (0, 1), rc\n"
        "print('torch' in sys.modules, 'kornia' in sys.modules)\n"
    )
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert res.stdout.split()[-2:] == ["False", "False"]


def test_report_rejudges_a_run_folder_of_the_older_config_layout(tmp_path, capsys, sample_scene):
    """config.json of runs before the gate / run_checks sections (issue #26): `pgt-check report`
    reads the moved settings at their new place, its flags set the new sections, and the
    config.json it rewrites has the current layout."""
    from pgt_check.config.judge import MOVED_KEYS

    out = tmp_path / "out"
    assert main([str(sample_scene / "trajectories.txt"), "--mesh",
                 str(sample_scene / "mesh.glb"), "--out", str(out), "--limit", "8",
                 "--report-details", "0", "-q"]) in (0, 1)
    cfg = json.loads((out / "config.json").read_text())
    old = {k: dict(v) if isinstance(v, dict) else v for k, v in cfg.items()}
    for (old_sec, old_key), (new_sec, new_key) in MOVED_KEYS.items():
        old[old_sec][old_key] = old[new_sec].pop(new_key)
    del old["gate"], old["run_checks"]
    old["verdict"]["max_fail_fraction"] = 1.0  # a stored setting of the older layout
    (out / "config.json").write_text(json.dumps(old))
    assert main(["report", str(out)]) == 0  # the stored gate setting is read: passes
    rewritten = json.loads((out / "config.json").read_text())
    assert rewritten["gate"]["max_fail_fraction"] == 1.0
    assert "max_fail_fraction" not in rewritten["verdict"]
    assert main(["report", str(out), "--max-fail-fraction", "0", "--shared-checks",
                 "false"]) == 1
    summary = json.loads((out / "summary.json").read_text())
    assert summary["settings"]["run_checks"]["enabled"] is False
    assert "shared_errors" not in summary
