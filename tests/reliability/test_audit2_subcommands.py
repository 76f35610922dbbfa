"""Second audit (#25), across the subcommands: any file name in every text output, output files
never written through symlinks nor over the run's own inputs, numeric options range-checked,
one-line input errors (exit 2) from ``compare``, ``enhance`` and ``report``, SIGTERM -> 130."""

from __future__ import annotations

import csv
import json
import os
import signal
import time
import xml.etree.ElementTree as ET

import numpy as np
import pytest


def _one_error_line(err: str, prefix: str) -> str:
    assert "Traceback" not in err, err
    lines = [ln for ln in err.strip().splitlines() if ln]
    assert len(lines) == 1 and lines[0].startswith(prefix), err
    return lines[0]


# -- any file name in every text output ------------------------------------------------------


def _tum_scene(scene, names: dict[int, bytes]):
    """The scene as TUM (poses from trajectories.txt) with images renamed to ``names``."""
    rows = []
    for line in (scene / "trajectories.txt").read_text().splitlines()[1:]:
        t, _, qw, qx, qy, qz, tx, ty, tz = [v.strip() for v in line.split(",")]
        rows.append(" ".join([t, tx, ty, tz, qx, qy, qz, qw]))
    (scene / "tum.txt").write_text("\n".join(rows) + "\n")
    folder = os.fsencode(scene / "images")
    for i, name in names.items():
        os.rename(os.path.join(folder, f"frame-{i:06d}.jpg".encode()), os.path.join(folder, name))
    return scene / "tum.txt"


def test_undecodable_and_control_character_names(scene, tmp_path, cli, case):
    traj = _tum_scene(scene, {0: b"frame\xff-000000.jpg", 1: b"=frame\n-000001.jpg"})
    out = tmp_path / "out"
    rc, _, err = cli(traj, "--mesh", scene / "mesh.glb", "--out", out, "--format", "tum",
                     "--images", scene / "images", "--camera", "PINHOLE,320,240,250,250,160.5,120.5",
                     "--limit", "2", "--report-details", "2", "-q")
    case("image names: undecodable byte, newline, '='", "0/1, every output written",
         f"{rc}: {sorted(p.name for p in out.iterdir())[:4]}")
    assert rc in (0, 1) and "Traceback" not in err
    text = (out / "frames.csv").read_bytes().decode("utf-8")
    assert len(text.strip().splitlines()) == 3  # header + one line per frame
    paths = [r["image_path"] for r in csv.DictReader(text.splitlines())]
    assert paths == ["frame\\xff-000000.jpg", "'=frame\\n-000001.jpg"]
    json.loads((out / "summary.json").read_bytes().decode("utf-8"))
    ET.fromstring((out / "junit.xml").read_bytes())
    (out / "report.html").read_bytes().decode("utf-8")
    assert not [p for p in out.rglob("*") if p.name.endswith(".tmp")]


def test_log_lines_stay_one_line():
    import logging

    from pgt_check.commands.common import OneLineFormatter

    rec = logging.LogRecord("pgt_check.x", logging.WARNING, __file__, 1, "image %s", ("a\nb\udcff",),
                            None)
    assert OneLineFormatter("%(message)s").format(rec) == "image a\\nb\\xff"


# -- outputs: formulas, the 180 deg frame, symlinks, inputs in --out --------------------------


def _transforms(path, names, turned=()):
    frames = []
    for i, name in enumerate(names):
        m = np.eye(4)
        m[:3, 3] = [0.1 * i, 0, 0]
        if name in turned:
            m[:3, :3] = np.diag([-1.0, 1.0, -1.0])  # 180 deg about y
        frames.append({"file_path": name, "transform_matrix": m.tolist()})
    path.write_text(json.dumps({"w": 64, "h": 48, "fl_x": 50, "frames": frames}))
    return path


def test_compare_outputs(tmp_path, cli, case):
    # a frame id with a line break is refused at read time (#39 item 9:
    # test_audit3_low::test_compare_frame_id_with_a_newline_exits_2); a comma and a tab stay
    names = ["=HYPERLINK(1).png", "b,\tc.png", "d.png", "e.png"]
    a = _transforms(tmp_path / "a.json", names)
    b = _transforms(tmp_path / "b.json", names, turned={"d.png"})
    out = tmp_path / "out"
    out.mkdir()
    victim = tmp_path / "victim.txt"
    victim.write_text("keep me")
    (out / "compare.csv").symlink_to(victim)
    rc, stdout, err = cli("compare", a, b, "--out", out)
    assert rc == 0 and "Traceback" not in err
    assert victim.read_text() == "keep me" and not (out / "compare.csv").is_symlink()
    text = (out / "compare.csv").read_text(encoding="utf-8")
    rows = list(csv.DictReader(text.splitlines()))
    assert len(text.strip().splitlines()) == 5
    assert rows[0]["frame_id"] == "'=HYPERLINK(1).png" and rows[1]["frame_id"] == "b,\tc.png"
    summary = json.loads((out / "compare.json").read_text())
    case("compare: a frame turned by 180 deg", "in the max", stdout.splitlines()[1][-60:])
    assert summary["drot_deg"]["max"] == pytest.approx(180.0)
    assert summary["shift_px"]["n_not_finite"] == 1 and "max inf" in stdout


def test_compare_refuses_to_overwrite_its_input(tmp_path, cli):
    out = tmp_path / "out"
    out.mkdir()
    a = _transforms(out / "compare.json", ["x.png", "y.png"])
    before = a.read_bytes()
    b = _transforms(tmp_path / "b.json", ["x.png", "y.png"])
    rc, _, err = cli("compare", a, b, "--out", out)
    assert rc == 2 and "overwrite" in _one_error_line(err, "pgt-check compare: error:")
    assert a.read_bytes() == before


def test_run_refuses_to_overwrite_its_input(scene, tmp_path, cli, base_args, case):
    out = tmp_path / "out"
    out.mkdir()
    traj = out / "corrected_trajectory.txt"
    traj.write_bytes((scene / "trajectories.txt").read_bytes())
    args = base_args(out=out)
    args[0] = str(traj)
    args += ["--sensors", str(scene / "sensors.txt"), "--images", str(scene / "images.txt")]
    rc, _, err = cli(*args)
    case("--out holds the run's own input (OUT/corrected_trajectory.txt)", "2, input untouched",
         f"{rc}: {err.strip().replace(str(tmp_path), '<tmp>')[-100:]}")
    assert rc == 2 and "would overwrite" in _one_error_line(err, "pgt-check: error:")
    assert not (out / "records.jsonl").exists()


def test_outputs_replace_symlinks_not_follow(scene, tmp_path, cli, base_args, case):
    out = tmp_path / "out"
    out.mkdir()
    victim = tmp_path / "victim.txt"
    victim.write_text("keep me")
    for name in ("frames.csv", "summary.json", "report.html", "frames.csv.tmp"):
        (out / name).symlink_to(victim)
    rc, _, err = cli(*base_args(out=out))
    # #39: a link no run of the tool wrote is the user's: refused (exit 2 naming it), kept
    case("symlinks at OUT/frames.csv, summary.json, report.html, frames.csv.tmp",
         "2 (not pgt-check's), target untouched", f"{rc}: target {victim.read_text()!r}, "
         f"frames.csv {'a link' if (out / 'frames.csv').is_symlink() else 'a regular file'}")
    assert rc == 2 and "not written by pgt-check" in err and victim.read_text() == "keep me"
    assert (out / "frames.csv").is_symlink()
    for name in ("frames.csv", "summary.json", "report.html"):
        (out / name).unlink()
    rc, _, _ = cli(*base_args(out=out))  # links at names a run wrote: test_audit3_files
    assert rc == 0 and victim.read_text() == "keep me"
    assert not (out / "frames.csv").is_symlink() and "frame_id" in (out / "frames.csv").read_text()


# -- numeric options of every subcommand -------------------------------------------------------


@pytest.mark.parametrize("argv", [
    ["--max-keypoints", "3000000000"],
    ["--edges-tile-grid", "100000"],
    ["--scheduler", "not a url"],
    ["--correct-rounds", "1000000000"],
])
def test_main_numeric_options(argv, cli, base_args, case):
    rc, _, err = cli(*base_args(*argv))
    line = _one_error_line(err, "pgt-check: error:")
    case(" ".join(argv), "2, one line", f"{rc}: {line[:120]}")
    assert rc == 2 and argv[0] in line


@pytest.mark.parametrize("argv", [["--tie-px", "nan"], ["--tie-px", "-1"], ["--limit", "0"],
                                  ["--threshold-px", "inf"]])
def test_compare_numeric_options(argv, tmp_path, cli, case):
    a = _transforms(tmp_path / "a.json", ["x.png"])
    rc, _, err = cli("compare", a, a, "--out", tmp_path / "o", *argv)
    line = _one_error_line(err, "pgt-check compare: error:")
    case(f"compare {' '.join(argv)}", "2, one line", f"{rc}: {line[:120]}")
    assert rc == 2


def test_compare_api_checks_options():
    from pgt_check.errors import InputError
    from pgt_check.stages.compare import compare_trajectories
    from pgt_check.types import Trajectory

    with pytest.raises(InputError):
        compare_trajectories(Trajectory(()), Trajectory(()), tie_px=float("nan"))


@pytest.mark.parametrize("argv", [["--limit", "0"], ["--short-side", "0"],
                                  ["--max-rotation-deg", "nan"], ["--translation-scale", "-1"],
                                  ["--iterations", "0"], ["--short-side", "1000000"],
                                  ["--iterations", "1001"]])
def test_enhance_numeric_options(argv, sample_scene, tmp_path, cli, case):
    rc, _, err = cli("enhance", sample_scene / "images", sample_scene / "trajectories.txt",
                     "--out", tmp_path / "o", *argv)
    line = _one_error_line(err, "pgt-check enhance: error:")
    case(f"enhance {' '.join(argv)}", "2, one line", f"{rc}: {line[:120]}")
    assert rc == 2 and argv[0] in line


# -- one-line errors of compare / enhance / report ---------------------------------------------


def test_compare_out_is_a_file(tmp_path, cli, case):
    a = _transforms(tmp_path / "a.json", ["x.png"])
    f = tmp_path / "file"
    f.write_text("x")
    rc, _, err = cli("compare", a, a, "--out", f)
    line = _one_error_line(err, "pgt-check compare: error:")
    case("compare --out FILE", "2, one line", f"{rc}: {line[-100:]}")
    assert rc == 2 and "not a folder" in line


@pytest.mark.parametrize("what", ["out_file", "mesh_txt", "renders_are_out"])
def test_enhance_errors(what, sample_scene, scene, tmp_path, cli, case):
    out = tmp_path / "o"
    extra: list[str] = []
    renders = sample_scene / "images"
    if what == "out_file":
        out.write_text("x")
    elif what == "mesh_txt":
        bad = tmp_path / "x.txt"
        bad.write_text("not a mesh")
        extra = ["--method", "reproject", "--mesh", str(bad)]
    else:
        out = scene
        renders = scene / "images"
        (scene / "images").rename(scene / "renders")
        (scene / "renders").rename(scene / "images")  # the renders are out/images
    rc, _, err = cli("enhance", renders, sample_scene / "trajectories.txt", "--out", out, "-q",
                     *extra)
    line = _one_error_line(err, "pgt-check enhance: error:")
    shown = line.replace(str(tmp_path), "<tmp>")
    case(f"enhance: {what}", "2, one line", f"{rc}: {shown[-110:]}")
    assert rc == 2


@pytest.fixture(scope="module")
def finished_run(sample_scene, tmp_path_factory):
    from pgt_check.cli import main

    out = tmp_path_factory.mktemp("run") / "out"
    assert main([str(sample_scene / "trajectories.txt"), "--mesh", str(sample_scene / "mesh.glb"),
                 "--out", str(out), "--limit", "2", "--report-details", "0", "-q"]) == 0
    return out


@pytest.mark.parametrize("what,content", [
    ("run.json", "[1, 2]"),
    ("run.json", '{"frame_ids": 5}'),
    ("run.json", '{"frame_ids": [{"a": 1}]}'),
    ("config.json", '"text"'),
    ("config.json", '{"limit": "x"}'),
    ("records.jsonl", None),
])
def test_report_on_malformed_run(what, content, finished_run, tmp_path, cli, case):
    import shutil

    out = tmp_path / "copy"
    shutil.copytree(finished_run, out)
    if content is None:  # a record whose fields have the wrong types
        recs = [json.loads(x) for x in (out / what).read_text().splitlines()]
        recs[-1]["center"] = "x"
        recs[-1]["raw"] = [1]
        content = "\n".join(json.dumps(r) for r in recs) + "\n"
    (out / what).write_text(content)
    rc, _, err = cli("report", out)
    line = _one_error_line(err, "pgt-check report: error:")
    case(f"report: {what} {content[:30]!r}", "2, one line", f"{rc}: {line[:120]}")
    assert rc == 2


# -- signals ---------------------------------------------------------------------------------


def test_report_sigterm_exits_130(finished_run, tmp_path, cli, monkeypatch, case):
    import shutil

    from pgt_check.verdict import apply as _unused  # noqa: F401 - loaded before the patch

    out = tmp_path / "copy"
    shutil.copytree(finished_run, out)

    import pgt_check.verdict as verdict

    real = verdict.judge_run

    def judge(*a, **k):
        os.kill(os.getpid(), signal.SIGTERM)
        time.sleep(2)
        return real(*a, **k)

    monkeypatch.setattr(verdict, "judge_run", judge)
    previous = signal.getsignal(signal.SIGTERM)
    try:
        rc, _, err = cli("report", out)
    finally:
        signal.signal(signal.SIGTERM, previous)
    case("SIGTERM during pgt-check report", "130", f"{rc}: {err.strip()[:110]}")
    assert rc == 130 and "interrupted" in err


def test_stuck_frame_ends_after_sigterm_grace(monkeypatch, case):
    from pgt_check.executor import common

    monkeypatch.setattr(common, "TERM_GRACE_S", 0.2)
    t0 = time.monotonic()
    with pytest.raises(KeyboardInterrupt), common.stop_on_sigint() as stop:
        os.kill(os.getpid(), signal.SIGTERM)
        while time.monotonic() - t0 < 10:  # a frame that never returns
            time.sleep(0.05)
    case("SIGTERM while a frame never returns (grace 0.2 s)", "stops after the grace",
         f"KeyboardInterrupt (-> 130) after {time.monotonic() - t0:.1f} s")
    assert stop.is_set() and time.monotonic() - t0 < 5


def test_sigint_still_waits_for_the_frame(monkeypatch):
    from pgt_check.executor import common

    monkeypatch.setattr(common, "TERM_GRACE_S", 0.1)
    with common.stop_on_sigint() as stop:
        os.kill(os.getpid(), signal.SIGINT)
        time.sleep(0.4)  # no deadline after SIGINT: the frame finishes
    assert stop.is_set()
