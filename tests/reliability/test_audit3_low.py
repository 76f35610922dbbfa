"""Third audit (#39), the low items 9-13: frame ids that would not stay one line are refused
at read time; a worker the pool (or a CI cancel) terminates ends without a native stack dump;
the accuracy line of ``--calibration-from`` names the trusted calibration; outputs follow the
umask; ``--threads`` beyond 4 x the cores is capped with a warning."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

from pgt_check.config import RunConfig


def _error_line(err: str) -> str:
    assert "Traceback" not in err
    return err.strip().splitlines()[-1] if err.strip() else ""


# -- 9: a frame id with a line break -----------------------------------------------------------


def _nerfstudio_scene(scene, names: dict[int, str], n: int = 3, moved: tuple[int, ...] = ()):
    """The scene's first ``n`` frames as a nerfstudio transforms.json; frame i's image renamed
    to ``names[i]`` (its file_path, hence its frame id), frames ``moved`` shifted 0.5 m."""
    from pgt_check.io import read_trajectory

    traj = read_trajectory(scene / "trajectories.txt")
    frames = []
    for i, f in enumerate(traj.frames[:n]):
        default = os.path.basename(f.image_path)
        name = names.get(i, default)
        if name != default:
            os.rename(scene / "images" / default, scene / "images" / name)
        m = np.array(f.world_from_cam, dtype=float)
        if i in moved:
            m[:3, 3] += (0.5, 0.0, 0.0)
        frames.append({"file_path": f"images/{name}",
                       "transform_matrix": (m @ np.diag([1.0, -1.0, -1.0, 1.0])).tolist()})
    cam = traj.frames[0].camera
    fx, fy, cx, cy = cam.params[:4]
    doc = {"w": cam.width, "h": cam.height, "fl_x": fx, "fl_y": fy, "cx": cx + 0.5,
           "cy": cy + 0.5, "frames": frames}
    (scene / "transforms.json").write_text(json.dumps(doc))
    return scene / "transforms.json"


@pytest.mark.parametrize("name", ["frame\n-000001.jpg", "frame\r-000001.jpg",
                                  "frame\u2028-000001.jpg", "frame\x1b[2J.jpg"])
def test_frame_id_with_a_line_break_is_refused_at_read_time(name, scene, tmp_path, cli, case):
    """The id of a FAIL frame used to split into several lines of bad_frames.txt (and of the
    trajectory files); an escaped id would not match the frame. Refused: exit 2 naming the
    file and the entry, nothing written."""
    traj = _nerfstudio_scene(scene, {1: name}, moved=(1,))
    out = tmp_path / "out"
    rc, _, err = cli(traj, "--mesh", scene / "mesh.glb", "--out", out, "--report-details", "0",
                     "-q")
    line = _error_line(err)
    case(f"nerfstudio file_path {name!r} (a FAIL frame)", "2, names file and entry",
         f"{rc}: {line[-150:]}")
    assert rc == 2 and "transforms.json" in line and "frames[1]" in line
    assert "line breaks" in line and "\n" not in line.strip()
    assert not out.exists()


def test_line_file_names_with_control_characters_name_the_line(tmp_path):
    from pgt_check.errors import FormatError
    from pgt_check.io import read_trajectory

    hloc = tmp_path / "results.txt"
    hloc.write_text("a.jpg 1 0 0 0 0 0 0\nb\x1b.jpg 1 0 0 0 0 0 0\n")
    with pytest.raises(FormatError, match=r"results.txt:2: expected the image name without"):
        read_trajectory(hloc, "hloc", camera="PINHOLE,64,48,50,50,32,24")
    d = tmp_path / "lamar"
    d.mkdir()
    (d / "sensors.txt").write_text("cam\x070, c, camera, PINHOLE, 64, 48, 50, 50, 32, 24\n")
    (d / "trajectories.txt").write_text("0, cam\x070, 1, 0, 0, 0, 0, 0, 0\n")
    (d / "images.txt").write_text("0, cam\x070, a.jpg\n")
    with pytest.raises(FormatError, match=r"sensors.txt:1: expected the sensor id without"):
        read_trajectory(d / "trajectories.txt", "lamar")


def test_api_in_memory_frame_id_with_a_newline_is_an_input_error(scene, tmp_path):
    from pgt_check.api import check
    from pgt_check.errors import InputError
    from pgt_check.io import read_trajectory

    traj = read_trajectory(scene / "trajectories.txt")
    bad = traj.frames[0].__class__(
        "a\nb", traj.frames[0].camera, traj.frames[0].world_from_cam,
        traj.frames[0].image_path, traj.frames[0].image_file,
    )
    frames = (bad, *traj.frames[1:2])
    with pytest.raises(InputError, match="line breaks"):
        check(type(traj)(frames, "", "lamar"), scene / "mesh.glb", out=tmp_path / "o")
    assert not (tmp_path / "o" / "records.jsonl").exists()


def test_compare_frame_id_with_a_newline_exits_2(tmp_path, cli):
    doc = {"w": 64, "h": 48, "fl_x": 50,
           "frames": [{"file_path": n, "transform_matrix": np.eye(4).tolist()}
                      for n in ("a.png", "b\nc.png")]}
    (tmp_path / "a.json").write_text(json.dumps(doc))
    rc, _, err = cli("compare", tmp_path / "a.json", tmp_path / "a.json", "--out",
                     tmp_path / "out")
    assert rc == 2 and "frames[1]" in _error_line(err)


# -- 10: a worker the pool terminates prints no native stack dump ------------------------------

DUMP_MARKS = ("*** SIGTERM", "stack trace", "*** Aborted at", "PC: @")


def _native_checker(**kw):
    """The executor tests' FakeChecker, built as the real checker is: after pycolmap (whose
    import installs glog's crash handler, SIGTERM included) is loaded in the worker."""
    import pycolmap  # noqa: F401

    from tests.pgt_check.test_executor import FakeChecker

    return FakeChecker(**kw)


def native_build_checker(config, references=None, panel_sink=None):
    """``runner.build_frame_checker`` for the CLI on fake frames (picklable by name)."""
    return _native_checker(delay_s=0.2)


def _python(script: str, *argv: str, **popen) -> subprocess.Popen:
    """``python -c script`` with this module importable by its full name (spawned workers
    unpickle its factories by that name; pytest names it otherwise)."""
    from tests.pgt_check.test_executor import HERE, REPO

    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(REPO), str(HERE)]),
               **popen.pop("env", {}))
    return subprocess.Popen([sys.executable, "-c", script, *argv], env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, **popen)


def test_surviving_worker_stops_without_a_stack_dump(tmp_path, case):
    """One worker dies (exit 3): the pool SIGTERMs the others. The survivors printed a 27-line
    glog dump each ("*** SIGTERM received ... stack trace") on the run's stderr."""
    pytest.importorskip("pycolmap")
    script = (
        "import functools, sys\n"
        "from pgt_check.config import RunConfig\n"
        "from pgt_check.executor import ExecutorStats, iter_results\n"
        "from tests.pgt_check.test_executor import make_frames\n"
        "from tests.reliability.test_audit3_low import _native_checker\n"
        "if __name__ == '__main__':\n"
        "    f = functools.partial(_native_checker, delay_s=0.3, crash_once_ids=('f000002',),\n"
        "                          marker_dir=sys.argv[1])\n"
        "    stats = ExecutorStats()\n"
        "    recs = list(iter_results(make_frames(6), f, RunConfig(executor='process', "
        "workers=2), stats=stats))\n"
        "    print(len(recs), stats.worker_crashes, sum(r.error == '' for r in recs))\n"
    )
    proc = _python(script, str(tmp_path))
    out, err = proc.communicate(timeout=300)
    n, crashes, ok = (int(v) for v in out.split())
    case("a process worker dies (exit 3): the pool stops the other", "recovered, no dump",
         f"{n} frames ({ok} measured), {crashes} crash(es), "
         f"{sum(m in err for m in DUMP_MARKS)} dump marks in {len(err.splitlines())} "
         "stderr lines")
    assert proc.returncode == 0 and n == ok == 6 and crashes >= 1, err[-2000:]
    assert not [m for m in DUMP_MARKS if m in err], err[-2000:]


def test_ci_cancel_of_the_process_group_prints_no_dump(tmp_path):
    """SIGTERM to the whole process group (a CI cancel): the run exits 130 and neither it nor
    its workers print a crash dump."""
    pytest.importorskip("pycolmap")
    script = (
        "import sys, functools\n"
        "import tests.pgt_check.test_executor as te\n"
        "from tests.reliability.test_audit3_low import native_build_checker\n"
        "te.fake_build_checker = native_build_checker\n"
        "sys.exit(te.cli_main(sys.argv[1:]))\n"
    )
    out = tmp_path / "out"
    proc = _python(script, "fake-trajectory.txt", "--mesh", "fake.ply", "--out", str(out), "-q",
                   "--executor", "process", "--workers", "2", env={"PGT_FAKE_FRAMES": "200"},
                   start_new_session=True)
    try:
        t_end = time.monotonic() + 120
        rec = out / "records.jsonl"
        while not (rec.is_file() and rec.read_bytes().count(b"\n") >= 3):
            assert proc.poll() is None, proc.communicate()
            assert time.monotonic() < t_end, "no progress"
            time.sleep(0.1)
        os.killpg(proc.pid, signal.SIGTERM)
        _, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    assert proc.returncode == 130, err
    assert not [m for m in DUMP_MARKS if m in err], err[-2000:]


# -- 11: the accuracy line of --remove-calibration --calibration-from --------------------------


def test_trusted_calibration_is_not_called_estimated_on_the_same_frames(case):
    """--calibration-from wins over --remove-calibration: the trusted calibration was removed,
    yet the accuracy line said the calibration was "estimated on the same frames" and stated
    no shared limit. Now both flags give what --calibration-from alone gives."""
    from tests.pgt_check.verdict.test_accuracy import SHARED, rows, run_accuracy_rows

    both = RunConfig.from_dict({"run_checks": {"remove_calibration": True,
                                               "calibration_from": "trusted/summary.json"}})
    trusted = RunConfig.from_dict({"run_checks": {"calibration_from": "trusted/summary.json"}})
    acc = run_accuracy_rows(rows(), SHARED, both, threshold_px=8.0)
    text = " ".join(acc.sentences)
    case("--remove-calibration --calibration-from X: the accuracy line",
         "no 'estimated on the same frames'", text[-160:])
    assert "same frames" not in text and "estimated on" not in text
    alone = run_accuracy_rows(rows(), SHARED, trusted, threshold_px=8.0)
    assert acc.limits == alone.limits and acc.sentences == alone.sentences
    assert acc.limits.shared_px is not None


# -- 12: outputs follow the umask --------------------------------------------------------------


@pytest.fixture
def umask():
    old = os.umask(0o022)
    os.umask(old)

    def _set(mask: int) -> None:
        os.umask(mask)

    yield _set
    os.umask(old)


def test_outputs_follow_the_umask(tmp_path, cli, base_args, umask, case):
    """Every output was 0600 whatever the umask (the atomic writer's mkstemp): a CI artifact
    uploader running as another user could not read them."""
    umask(0o022)
    out = tmp_path / "out"
    rc, _, err = cli(*base_args(out=out))
    assert rc in (0, 1), err
    modes = {p.relative_to(out).as_posix(): p.stat().st_mode & 0o777
             for p in out.rglob("*") if p.is_file()}
    wrong = {k: oct(v) for k, v in modes.items() if v != 0o644}
    case("outputs under umask 022", "every file 0644",
         f"{len(modes)} files, {len(wrong)} not 0644: {sorted(wrong)[:3]}")
    assert {"frames.csv", "summary.json", "records.jsonl", "run.json"} <= set(modes)
    assert not wrong


@pytest.mark.parametrize("mask", [0o077, 0o002, 0o027])
def test_atomic_writer_follows_the_umask(mask, tmp_path, umask):
    from pgt_check.common.files import atomic_write_text, current_umask

    umask(mask)
    assert current_umask() == mask
    atomic_write_text(tmp_path / "f.txt", "x")
    assert (tmp_path / "f.txt").stat().st_mode & 0o777 == 0o666 & ~mask


# -- 13: --threads far beyond the cores --------------------------------------------------------


def test_threads_beyond_four_per_core_are_capped_with_a_warning(tmp_path, cli, base_args,
                                                                monkeypatch, case):
    """--threads 4096 was applied as given (OpenCV started 4096 threads: a 3-frame run took 13x
    as long). Capped at 4 x the usable cores with one warning; the setting is kept as given
    (config.json), the verdicts do not depend on it."""
    import cv2

    from pgt_check.threads import MAX_THREADS_PER_CORE, usable_cores

    applied: list[int] = []
    real = cv2.setNumThreads
    monkeypatch.setattr(cv2, "setNumThreads", lambda n: (applied.append(int(n)), real(n))[1])
    out = tmp_path / "out"
    rc, _, err = cli(*base_args("--threads", "4096", out=out))
    cap = MAX_THREADS_PER_CORE * usable_cores()
    warned = [ln for ln in err.splitlines() if "threads 4096" in ln]
    case("--threads 4096", f"capped at 4 x cores ({cap}), one warning",
         f"{rc}: applied {sorted(set(applied))}; {warned[0][-90:] if warned else 'no warning'}")
    assert rc in (0, 1), err
    assert applied and max(applied) <= cap and cap in applied
    assert len(warned) == 1 and f"using {cap}" in warned[0]
    assert json.loads((out / "config.json").read_text())["threads"] == 4096
    rc1, _, err1 = cli(*base_args("--threads", "4096", out=tmp_path / "o1"))
    assert "threads 4096" in err1  # -q keeps warnings


def test_threads_within_the_cap_are_applied_as_given(monkeypatch):
    from pgt_check.threads import capped, usable_cores

    cap = 4 * usable_cores()
    assert capped(None) is None and capped(1) == 1 and capped(cap) == cap
    assert capped(cap + 1) == cap and capped(4096) == min(4096, cap)
