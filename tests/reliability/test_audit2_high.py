"""Second hostile-input audit (issue #25), High: a green gate on wrong or stale results.

Each test runs real behaviour on the sample scene (copied per test) or small generated data:
the Python API keyed like the CLI, mesh side files in the content hash, strict booleans,
a frame off the mesh that its neighbours see (``off_mesh``), poses without images counted, the
run lock held until the output set is complete, and config replay without one-shot actions."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from pgt_check.errors import InputError

FAST = {"report_details": 0, "enhance": {"mode": "never"}, "correct": {"frames": "none"}}


def _move_lamar_row(traj: Path, row: int, dx: float) -> None:
    """Move the camera centre of data row ``row`` of a LaMAR trajectories file by ``dx`` in x."""
    lines = traj.read_text().splitlines()
    parts = lines[row + 1].split(",")
    parts[6] = f" {float(parts[6]) + dx:.9f}"
    lines[row + 1] = ",".join(parts)
    traj.write_text("\n".join(lines) + "\n")


# -- 1. the Python API reuses nothing whose content changed ------------------------------------
def test_api_pose_moved_in_place_is_measured_again(scene, tmp_path, case):
    from pgt_check.api import check

    out = tmp_path / "out"
    traj, mesh = scene / "trajectories.txt", scene / "mesh.glb"
    first = check(traj, mesh, out=str(out), limit=2, **FAST)
    _move_lamar_row(traj, 0, 0.5)  # frame 0 moves 0.5 m
    again = check(traj, mesh, out=str(out), limit=2, **FAST)
    fresh = check(traj, mesh, out=str(tmp_path / "fresh"), limit=2, **FAST)
    case("API: pose moved 0.5 m, check() again into the same out", "FAIL as a fresh out",
         f"first {list(first['verdict'])}, again {list(again['verdict'])}, "
         f"fresh {list(fresh['verdict'])}")
    assert list(first["verdict"]) == ["PASS", "PASS"]
    assert again.loc[0, "verdict"] == "FAIL"
    assert list(again["verdict"]) == list(fresh["verdict"])
    assert again.attrs["summary"]["gate"]["passed"] is False


def test_api_in_memory_pose_moved_is_measured_again(scene, tmp_path):
    from pgt_check.api import check
    from pgt_check.io import read_trajectory
    from pgt_check.types import Trajectory

    out, mesh = str(tmp_path / "out"), scene / "mesh.glb"
    traj = read_trajectory(scene / "trajectories.txt")
    frames = list(traj.frames[:2])
    assert list(check(Trajectory(frames), mesh, out=out, **FAST)["verdict"]) == ["PASS", "PASS"]
    moved = frames[1].world_from_cam.copy()
    moved[0, 3] += 0.5
    frames[1] = frames[1].with_pose(moved)
    df = check(Trajectory(frames), mesh, out=out, **FAST)
    assert df.loc[1, "verdict"] == "FAIL"


def test_api_moved_mesh_is_not_reused(scene, tmp_path, case):
    import trimesh

    from pgt_check.api import check

    out = str(tmp_path / "out")
    traj, mesh = scene / "trajectories.txt", scene / "mesh.glb"
    assert list(check(traj, mesh, out=out, limit=2, **FAST)["verdict"]) == ["PASS", "PASS"]
    moved = trimesh.load(str(mesh), process=False)
    moved.apply_translation([0.5, 0.0, 0.0])  # the whole mesh moves 0.5 m
    moved.export(str(mesh))
    # #39: the API measures changed inputs again by default (the CLI's --resume);
    # resume=False refuses as the CLI does without --resume
    with pytest.raises(InputError, match="inputs.mesh") as err:
        check(traj, mesh, out=out, limit=2, resume=False, **FAST)
    df = check(traj, mesh, out=out, limit=2, **FAST)
    case("API: whole mesh moved 0.5 m, check() again into the same out",
         "measured again (FAIL); with resume=False: InputError naming inputs.mesh",
         f"{list(df['verdict'])}; resume=False: {str(err.value)[:90]}...")
    assert "FAIL" in list(df["verdict"])


# -- 2. what the mesh loader reads is in the content hash --------------------------------------
def _export(scene: Path, dst: Path, name: str) -> Path:
    import trimesh

    dst.mkdir()
    trimesh.load(str(scene / "mesh.glb"), process=False).export(str(dst / name))
    return dst / name


def test_obj_texture_replaced_is_a_changed_mesh(scene, tmp_path, cli, base_args, case):
    obj = _export(scene, tmp_path / "objmesh", "mesh.obj")
    textures = sorted((tmp_path / "objmesh").glob("material_*.png"))
    assert textures and (tmp_path / "objmesh" / "material.mtl").is_file()
    args = base_args("--enhance", "never", "--correct", "none")
    args[args.index("--mesh") + 1] = str(obj)
    assert cli(*args)[0] == 0
    import cv2

    for texture in textures:  # every texture flipped upside down: another render
        cv2.imwrite(str(texture), np.ascontiguousarray(cv2.imread(str(texture))[::-1]))
    rc, _, err = cli(*args)
    last = err.strip().splitlines()[-1] if err.strip() else ""
    case("OBJ texture PNG replaced, rerun into the same --out", "2, names inputs.mesh",
         f"{rc}: {last[:120]}")
    assert rc == 2 and "inputs.mesh" in last


def test_gltf_buffers_and_mtl_are_hashed(scene, tmp_path, case):
    from pgt_check.content_hash import content_hash, mesh_content_hash
    from pgt_check.render import load_mesh

    gltf = _export(scene, tmp_path / "gltf", "mesh.gltf")
    mesh = load_mesh(gltf)
    buffers = [f for f in mesh.side_files if f.endswith(".bin")]
    assert buffers, mesh.side_files
    before = mesh_content_hash(gltf, mesh.side_files)
    assert before != content_hash(gltf)
    data = bytearray(Path(buffers[-1]).read_bytes())
    data[-1] ^= 0xFF  # one byte of an external buffer
    Path(buffers[-1]).write_bytes(bytes(data))
    assert mesh_content_hash(gltf, load_mesh(gltf).side_files) != before
    # the MTL of an OBJ too, and a texture that is missing, then appears
    obj = _export(scene, tmp_path / "obj", "mesh.obj")
    png = tmp_path / "obj" / "material_0.png"
    with_png = mesh_content_hash(obj, load_mesh(obj).side_files)
    png.rename(tmp_path / "aside.png")
    side = load_mesh(obj).side_files
    assert "missing:material_0.png" in side
    assert mesh_content_hash(obj, side) != with_png
    case("glTF: one byte of an external .bin buffer changed; OBJ texture removed",
         "a different mesh hash", f"hash changed ({len(mesh.side_files)} side files hashed)")


# -- 3. booleans: the usual spellings, anything else is a usage error --------------------------
def test_report_boolean_flags_are_strict(cli, base_args, tmp_path, case):
    out = tmp_path / "out"
    assert cli(*base_args())[0] == 0
    rc, stdout, _ = cli("report", out, "--shared-checks", "on")
    summary = json.loads((out / "summary.json").read_text())
    assert rc == 0 and summary["settings"]["run_checks"]["enabled"] is True
    assert "shared_errors" in summary  # the run-level checks ran
    for flag, word in (("--shared-checks", "ture"), ("--remove-calibration", "ture"),
                       ("--shared-checks", "2")):
        rc, _, err = cli("report", out, flag, word)
        lines = err.strip().splitlines()
        case(f"report {flag} {word}", "2, one line", f"{rc}: {lines[-1][:110]}")
        assert rc == 2 and len(lines) == 1 and flag in lines[0] and word in lines[0]
    for word, value in (("OFF", False), ("No", False), ("1", True), ("Yes", True)):
        assert cli("report", out, "--shared-checks", word)[0] == 0
        summary = json.loads((out / "summary.json").read_text())
        assert summary["settings"]["run_checks"]["enabled"] is value


def test_config_file_booleans_are_strict(cli, base_args, tmp_path, case):
    cfg = tmp_path / "c.json"
    cfg.write_text(json.dumps({"run_checks": {"enabled": "ture"}}))
    rc, _, err = cli(*base_args("--config", cfg))
    last = err.strip().splitlines()[-1]
    case("config file run_checks.enabled: \"ture\"", "2, names the key", f"{rc}: {last[:110]}")
    assert rc == 2 and "RunChecksConfig.enabled" in last and "ture" in last
    cfg.write_text(json.dumps({"run_checks": {"enabled": "off"}}))
    assert cli(*base_args("--config", cfg))[0] == 0
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert summary["settings"]["run_checks"]["enabled"] is False


# -- (Medium, same run code) the lock is held until the output set is complete; config replay --
def test_run_lock_held_until_outputs_complete(cli, base_args, tmp_path, monkeypatch, case):
    from pgt_check.report import outputs
    from pgt_check.store import RecordStore

    out = tmp_path / "out"
    seen: list[str] = []
    real = outputs.write_summary  # what a run's write_outcome (and write_outputs) write through

    def probing(*args, **kwargs):  # a second run arriving while the outputs are written
        try:
            with RecordStore.open(out, "another-run", resume=True):
                seen.append("opened")
        except InputError as err:
            seen.append(str(err))
        return real(*args, **kwargs)

    monkeypatch.setattr(outputs, "write_summary", probing)
    rc, _, _ = cli(*base_args("--correct", "all"))
    case("a second run opens --out while the first writes its outputs", "refused (locked)",
         f"{rc}: {seen[0][-70:] if seen else 'not probed'}")
    assert rc == 0 and len(seen) == 1 and "another pgt-check run" in seen[0]
    assert (out / "outputs.complete.json").is_file()


def test_config_replay_does_not_replay_overwrite_or_resume(cli, base_args, tmp_path, case):
    out = tmp_path / "out"
    assert cli(*base_args("--overwrite"))[0] == 0
    stored = json.loads((out / "config.json").read_text())
    assert "overwrite" not in stored and "resume" not in stored
    rc, _, _ = cli("--config", out / "config.json", "-q")  # plain replay keeps the records
    reused = json.loads((out / "summary.json").read_text())["executor"]["frames_reused"]
    rc2, _, err = cli("--config", out / "config.json", "--resume", "-q")
    case("--config OUT/config.json of an --overwrite run: replay, then replay --resume",
         "0 reusing the 2 stored frames; 0", f"{rc} (reused {reused}); {rc2} {err.strip()[:60]}")
    assert rc == 0 and reused == 2 and rc2 == 0
    # an older config.json (or any config file) that sets an action: ignored, not obeyed
    old = dict(stored, overwrite=True)
    (tmp_path / "old.json").write_text(json.dumps(old))
    assert cli("--config", tmp_path / "old.json", "-q")[0] == 0
    assert json.loads((out / "summary.json").read_text())["executor"]["frames_reused"] == 2


# -- 5. every pose of the input is checked or counted ------------------------------------------
def test_tum_poses_without_images_are_counted(scene, tmp_path, cli, case):
    import shutil

    from pgt_check.io import read_trajectory
    from pgt_check.io.writers import tum_text

    tum = tmp_path / "tum"
    (tum / "images").mkdir(parents=True)
    traj = read_trajectory(scene / "trajectories.txt")
    (tum / "groundtruth.txt").write_text(tum_text(traj))
    for name in ("frame-000000.jpg", "frame-000001.jpg", "frame-000002.jpg"):
        shutil.copy(scene / "images" / name, tum / "images" / name)
    out = tmp_path / "out"
    rc, stdout, _ = cli(tum / "groundtruth.txt", "--mesh", scene / "mesh.glb", "--camera",
                        "PINHOLE,320,240,250,250,160,120", "--images", tum / "images", "--out",
                        out, "--report-details", "0", "--enhance", "never", "-q")
    summary = json.loads((out / "summary.json").read_text())
    reasons = [r for r in (out / "frames.csv").read_text().splitlines()[1:] if "image_missing" in r]
    case("TUM: 24 poses, images for 3", "24 frames (21 image_missing), gate fails (1)",
         f"{rc}: {summary['n_frames']} frames, {len(reasons)} image_missing")
    assert len(traj) == 24 and summary["n_frames"] == 24 and len(reasons) == 21
    assert rc == 1 and summary["gate"]["passed"] is False


def test_lamar_poses_without_image_rows_are_counted(scene, cli, base_args, tmp_path, case):
    images = scene / "images.txt"
    lines = images.read_text().splitlines()
    images.write_text("\n".join(lines[:4]) + "\n")  # image rows for 3 of the 24 poses
    out = tmp_path / "out"
    args = base_args("--enhance", "never")
    rc, _, _ = cli(*args[: args.index("--limit")], *args[args.index("--limit") + 2:])
    summary = json.loads((out / "summary.json").read_text())
    rows = (out / "frames.csv").read_text().splitlines()[1:]
    case("LaMAR: 24 poses, image rows for 3", "24 frames (21 image_missing), gate fails (1)",
         f"{rc}: {summary['n_frames']} frames, "
         f"{sum('image_missing' in r for r in rows)} image_missing")
    assert summary["n_frames"] == 24 and sum("image_missing" in r for r in rows) == 21
    assert rc == 1


def test_lamar_rig_pose_without_any_image_is_a_frame(tmp_path):
    from pgt_check.io import read_trajectory

    (tmp_path / "sensors.txt").write_text(
        "c0, c0, camera, PINHOLE, 64, 48, 50, 50, 32, 24\n"
        "c1, c1, camera, PINHOLE, 64, 48, 50, 50, 32, 24\n"
        "d0, depth, depth, PINHOLE, 64, 48, 50, 50, 32, 24\n"
    )
    (tmp_path / "rigs.txt").write_text(
        "rig, c0, 1, 0, 0, 0, 0, 0, 0\nrig, c1, 1, 0, 0, 0, 0.1, 0, 0\n"
    )
    (tmp_path / "trajectories.txt").write_text(
        "0, rig, 1, 0, 0, 0, 0, 0, 0\n1, rig, 1, 0, 0, 0, 1, 0, 0\n"
        "2, c1, 1, 0, 0, 0, 2, 0, 0\n3, d0, 1, 0, 0, 0, 3, 0, 0\n"
    )
    (tmp_path / "images.txt").write_text("0, c1, a.jpg\n")
    frames = read_trajectory(tmp_path / "trajectories.txt").by_id()
    # rig pose 0 is checked through c1's image; rig pose 1 (no image of c0 or c1) and camera
    # pose 2 are frames without an image; the depth sensor's pose is no image's pose
    assert sorted(frames) == ["0/c1", "1/c0", "2/c1"]
    assert frames["1/c0"].image_file is None and frames["2/c1"].image_file is None
    np.testing.assert_allclose(frames["1/c0"].world_from_cam[:3, 3], [1, 0, 0])


# -- 4. the worse the pose, the softer the verdict: no more -----------------------------------
def test_frame_moved_30m_off_the_mesh_fails(scene, tmp_path, cli, case):
    from pgt_check.api import check
    from pgt_check.io import read_trajectory
    from pgt_check.types import Trajectory

    frames = list(read_trajectory(scene / "trajectories.txt").frames[:7])
    moved = frames[3].world_from_cam.copy()
    moved[2, 3] += 30.0  # 30 m up: the render shows nothing of the room
    frames[3] = frames[3].with_pose(moved)
    out = tmp_path / "out"
    df = check(Trajectory(frames), scene / "mesh.glb", out=str(out), **FAST)
    case("a frame moved 30 m off the mesh (neighbours see it well)", "FAIL off_mesh, gate fails",
         f"{df.loc[3, 'verdict']} {df.loc[3, 'reason'][:60]}; gate passed: "
         f"{df.attrs['summary']['gate']['passed']}")
    assert df.loc[3, "verdict"] == "FAIL" and df.loc[3, "reason"].startswith("off_mesh")
    assert list(df["verdict"]).count("PASS") == 6
    assert df.attrs["summary"]["gate"]["passed"] is False
    # re-judging the stored records gives the same verdict
    rc, _, _ = cli("report", out)
    rows = (out / "frames.csv").read_text().splitlines()
    assert rc == 1 and "off_mesh" in rows[4]


def _measured(coverages: list[float | None], min_coverage: float = 0.05):
    """Measurements with these render coverages (None: not rendered, image missing)."""
    from dataclasses import replace

    from pgt_check.measure.record import MeasureReason, failed_measurement
    from pgt_check.types import Camera, Frame

    cam = Camera("PINHOLE", 64, 48, (50.0, 50.0, 32.0, 24.0))
    out = []
    for i, c in enumerate(coverages):
        frame = Frame(str(i), cam, np.eye(4), f"{i}.png")
        if c is None:
            out.append(failed_measurement(frame, MeasureReason.IMAGE_MISSING))
            continue
        low = MeasureReason.LOW_COVERAGE if c < min_coverage else MeasureReason.NONE
        out.append(replace(failed_measurement(frame, low), coverage=c))
    return out


def test_off_mesh_compares_with_the_neighbourhood():
    from pgt_check.verdict.off_mesh import off_mesh_frames

    # one frame sees nothing among frames that see the mesh well; a missing image between
    # them is passed over; the first frame of a trajectory has neighbours on one side
    got = off_mesh_frames(_measured([0.0, 0.8, 0.9, None, 0.01, 0.7, 0.9, 0.85]), 0.05)
    assert sorted(got) == ["0", "4"]
    # a segment outside the scanned area: its inner frames keep low_coverage (their whole
    # neighbourhood covers little); a gradual exit never FAILs
    seg = [0.9, 0.8, 0.9, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.9, 0.8, 0.9]
    assert not {"5", "6", "7"} & set(off_mesh_frames(_measured(seg), 0.05))
    fade = [0.6, 0.4, 0.25, 0.12, 0.06, 0.04, 0.02, 0.01, 0.0, 0.0, 0.0]
    assert off_mesh_frames(_measured(fade), 0.05) == {}
    # neighbours that barely see the mesh themselves (median < 2 x min_coverage) vouch for
    # nothing; a frame at the min_coverage level or above is matched, not judged here
    assert off_mesh_frames(_measured([0.08, 0.09, 0.0, 0.08, 0.09]), 0.05) == {}
    assert off_mesh_frames(_measured([0.9, 0.9, 0.06, 0.9, 0.9]), 0.05) == {}
    # a lone frame (no neighbours) stays low_coverage
    assert off_mesh_frames(_measured([0.0]), 0.05) == {}
