"""``python -m pgt_check`` behaves exactly like the ``pgt-check`` console script."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

from pgt_check.cli import main

REPO = Path(__file__).resolve().parents[2]


def _run_module(*args: str) -> subprocess.CompletedProcess:
    env = {
        **os.environ,
        "PYTHONPATH": os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")]),
    }
    return subprocess.run(
        [sys.executable, "-m", "pgt_check", *args],
        capture_output=True,
        text=True,
        env=env,
        cwd=REPO,
        timeout=120,
    )


def test_main_module_calls_the_console_script_main():
    import tomllib

    import pgt_check.__main__ as entry

    scripts = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]["scripts"]
    assert scripts["pgt-check"] == "pgt_check.cli:main"
    assert entry.main is main


def test_help_version_and_usage_errors(capsys):
    res = _run_module("--help")
    assert res.returncode == 0
    assert main(["--help"]) == 0
    assert res.stdout == capsys.readouterr().out  # the same parser, the same text
    assert "--mesh" in res.stdout and "Exit codes" in res.stdout

    res = _run_module("--version")
    assert res.returncode == 0 and res.stdout.startswith("pgt-check ")

    res = _run_module("--no-such-flag")  # one line, no usage block (--help shows it)
    assert res.returncode == 2 and res.stderr == (
        "pgt-check: error: unrecognized arguments: --no-such-flag (see pgt-check --help)\n")

    res = _run_module("report", "--help")
    assert res.returncode == 0 and "--max-fail-fraction" in res.stdout


def test_input_errors_exit_two(tmp_path):
    t = tmp_path / "t.txt"
    t.write_text("# nothing\n")
    res = _run_module(str(t), "--mesh", str(tmp_path / "nope.glb"), "--out", str(tmp_path / "o"))
    assert res.returncode == 2 and "mesh not found" in res.stderr
    res = _run_module("report", str(tmp_path / "not-a-run"))
    assert res.returncode == 2


def test_gate_exit_codes(tmp_path, sample_scene):
    # two sample frames: frame 2 is right, frame 3 is rotated by 3.5 degrees (perturbed.txt)
    for name in ("sensors.txt", "mesh.glb"):
        shutil.copy(sample_scene / name, tmp_path / name)
    (tmp_path / "images").mkdir()
    for name in ("trajectories.txt", "images.txt"):
        lines = (sample_scene / name).read_text().splitlines()
        keep = [ln for ln in lines[1:] if ln.split(",")[0].strip() in ("2", "3")]
        (tmp_path / name).write_text("\n".join([lines[0], *keep]) + "\n")
    for i in (2, 3):
        shutil.copy(sample_scene / f"images/frame-00000{i}.jpg", tmp_path / "images")
    out = tmp_path / "out"
    res = _run_module(
        str(tmp_path / "trajectories.txt"),
        "--mesh",
        str(tmp_path / "mesh.glb"),
        "--out",
        str(out),
        "--preset",
        "fast",
        "-q",
    )
    assert res.returncode == 1, res.stderr  # gate failed: one FAIL frame
    assert "1 FAIL" in res.stdout + res.stderr
    assert (out / "report.html").is_file() and (out / "junit.xml").is_file()
    # a laxer gate on the same measurements (report subcommand, nothing recomputed) passes
    res = _run_module("report", str(out), "--max-fail-fraction", "1.0")
    assert res.returncode == 0, res.stderr
