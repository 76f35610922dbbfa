"""Class 7: a consistent output set (completion marker written last; ``pgt-check report``
rebuilds an incomplete set) and SIGTERM handled like SIGINT (exit 130, resume hint)."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

from pgt_check.report.outputs import COMPLETION_MARKER, outputs_complete

REPO = Path(__file__).resolve().parents[2]


def test_marker_written_last_and_checked(cli, base_args, tmp_path, case):
    out = tmp_path / "out"
    assert cli(*base_args())[0] == 0
    assert outputs_complete(out) == (True, "")
    files = json.loads((out / COMPLETION_MARKER).read_text())["files"]
    assert {"frames.csv", "summary.json", "report.html", "junit.xml"} <= set(files)
    # a set cut short: junit.xml older than summary.json, no marker (kill -9 midway)
    (out / "junit.xml").write_text("<testsuites/>")
    assert not outputs_complete(out)[0]
    (out / COMPLETION_MARKER).unlink()
    rc, _, err = cli("report", str(out))
    case("outputs cut short (junit.xml stale, no marker); pgt-check report", "rebuilt, marker back",
         f"{rc}: {err.strip().splitlines()[-1][:120]}")
    assert rc == 0 and "incomplete" in err and outputs_complete(out) == (True, "")
    assert "testcase" in (out / "junit.xml").read_text()


def test_sigterm_is_handled_like_sigint(scene, tmp_path, case):
    out = tmp_path / "out"
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    cmd = [sys.executable, "-m", "pgt_check", str(scene / "trajectories.txt"), "--mesh",
           str(scene / "mesh.glb"), "--out", str(out), "--report-details", "0", "-q"]
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True)
    records = out / "records.jsonl"
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline and proc.poll() is None:
        if records.is_file() and records.stat().st_size > 0:
            break
        time.sleep(0.1)
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=60)
    case("SIGTERM during the run", "130, resume hint, no crash dump",
         f"{proc.returncode}: {err.strip().splitlines()[-1][:100]}")
    assert proc.returncode == 130
    assert "resume with: pgt-check" in err and "--resume" in err
    assert "Traceback" not in err and "*** SIGTERM" not in err and "PC: @" not in err
    assert not (out / COMPLETION_MARKER).exists()
