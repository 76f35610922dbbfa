"""``pgt-check enhance``: renders made with the project renderer at the sample scene's poses,
enhanced end to end (shipped MaRINeR weights, reprojection), metrics against the photos."""

from __future__ import annotations

import csv
import json
import math
from pathlib import Path

import numpy as np
import pytest

from pgt_check.cli import main
from pgt_check.io import load_image, read_trajectory
from pgt_check.stages.enhance_folder import (
    METRIC_COLUMNS,
    REFERENCE_COLUMNS,
    RenderItem,
    frame_index,
    nearest_references,
)
from pgt_check.types import Camera, Frame

#: frames whose own pose and whose neighbours' poses are unperturbed (perturbed.txt: 3, 7, 11)
FRAMES = (5, 13, 19)
GL_FROM_CV = np.diag([1.0, -1.0, -1.0, 1.0])


def _save(path: Path, rgb: np.ndarray) -> None:
    from PIL import Image

    Image.fromarray(np.round(np.clip(rgb, 0, 1) * 255).astype(np.uint8)).save(path)


def _render_frames(mesh: Path, frames: list[Frame], folder: Path, scale: float,
                   names: list[str]) -> list[Camera]:
    from pgt_check.render import load_mesh, make_renderer

    folder.mkdir(parents=True, exist_ok=True)
    renderer = make_renderer(load_mesh(mesh))
    cams = []
    try:
        for f, name in zip(frames, names, strict=True):
            cam = f.camera.as_pinhole().scaled(scale)
            _save(folder / f"{name}.png", renderer.render(cam, f.world_from_cam).rgb)
            cams.append(cam)
    finally:
        renderer.close()
    return cams


@pytest.fixture(scope="module")
def scene_renders(sample_scene: Path, tmp_path_factory) -> Path:
    """Half-size renders (160x120) of three sample frames, named like the model's images."""
    traj = read_trajectory(sample_scene / "trajectories.txt")
    frames = [traj.frames[i] for i in FRAMES]
    folder = tmp_path_factory.mktemp("renders")
    _render_frames(sample_scene / "mesh.glb", frames, folder, 0.5,
                   [Path(f.image_path).stem for f in frames])
    return folder


def _rows(path: Path) -> list[dict[str, str]]:
    with path.open(newline="") as fh:
        return list(csv.DictReader(fh))


def test_mariner_enhances_named_renders_and_scores_them(scene_renders, sample_scene, tmp_path,
                                                        capsys):
    out = tmp_path / "out"
    rc = main(["enhance", str(scene_renders), str(sample_scene / "trajectories.txt"),
               "--out", str(out), "--gt", str(sample_scene / "images"), "--short-side", "64",
               "-q"])
    assert rc == 0, capsys.readouterr().err
    names = [f"frame-{i:06d}" for i in FRAMES]
    for name in names:
        enhanced = load_image(out / "images" / f"{name}.png")
        raw = load_image(scene_renders / f"{name}.png")
        assert enhanced.shape == raw.shape == (120, 160, 3)
        assert np.abs(enhanced - raw).mean() > 1e-3  # changed, not a copy of the render
    refs = _rows(out / "references.csv")
    assert list(refs[0]) == list(REFERENCE_COLUMNS)
    for row, i in zip(refs, FRAMES, strict=True):
        assert row["status"] == "ok" and row["pose"] == f"{i}/cam0"
        ref_index = int(Path(row["reference"]).stem.split("-")[1])
        assert ref_index != i and abs(ref_index - i) <= 2  # nearest other photo, never its own
    rows = _rows(out / "metrics.csv")
    assert list(rows[0]) == list(METRIC_COLUMNS) and [r["render"] for r in rows] == names
    for r in rows:
        vals = [float(r[k]) for k in METRIC_COLUMNS[2:]]
        assert all(math.isfinite(v) for v in vals)
        assert 8.0 < float(r["psnr_y_raw"]) < 40.0 and 0.0 < float(r["lpips_raw"]) < 1.0
    md = (out / "metrics.md").read_text()
    assert "| **mean (3)** |" in md and "PSNR-Y enhanced" in md
    assert "PSNR-Y" in capsys.readouterr().out


def _transforms(frames: list[Frame], cams: list[Camera], paths: list[str]) -> dict:
    entries = []
    for f, cam, p in zip(frames, cams, paths, strict=True):
        fx, fy = cam.focal
        cx, cy = cam.principal_point
        entries.append({
            "file_path": p, "w": cam.width, "h": cam.height, "fl_x": fx, "fl_y": fy,
            "cx": cx + 0.5, "cy": cy + 0.5,
            "transform_matrix": (f.world_from_cam @ GL_FROM_CV).tolist(),
        })
    return {"camera_model": "OPENCV", "frames": entries}


def test_reproject_with_transforms_json_and_render_poses_file(sample_scene, tmp_path, capsys):
    """Model = a nerfstudio transforms.json; renders named freely, posed by --render-poses."""
    traj = read_trajectory(sample_scene / "trajectories.txt")
    model = tmp_path / "transforms.json"
    model.write_text(json.dumps(_transforms(
        list(traj.frames), [f.camera for f in traj.frames],
        [str(sample_scene / f.image_path) for f in traj.frames])))
    frames = [traj.frames[i] for i in FRAMES]
    names = [f"view_{k}" for k in range(len(frames))]
    renders = tmp_path / "renders"
    cams = _render_frames(sample_scene / "mesh.glb", frames, renders, 0.5, names)
    poses = tmp_path / "render_poses.json"
    poses.write_text(json.dumps(_transforms(frames, cams, [f"{n}.png" for n in names])))
    gt = tmp_path / "gt"
    gt.mkdir()
    for f, n in zip(frames, names, strict=True):  # photos named like the renders
        (gt / f"{n}.jpg").write_bytes(Path(f.image_file).read_bytes())
    out = tmp_path / "out"
    rc = main(["enhance", str(renders), str(model), "--render-poses", str(poses),
               "--method", "reproject", "--mesh", str(sample_scene / "mesh.glb"),
               "--out", str(out), "--gt", str(gt), "--no-lpips", "-q"])
    assert rc == 0, capsys.readouterr().err
    refs = _rows(out / "references.csv")
    assert [r["pose"] for r in refs] == [f"{n}.png" for n in names]
    for r, i in zip(refs, FRAMES, strict=True):
        assert Path(r["reference"]).name in {f"frame-{i - 1:06d}.jpg", f"frame-{i + 1:06d}.jpg"}
    rows = _rows(out / "metrics.csv")
    assert len(rows) == 3
    for r in rows:
        assert math.isfinite(float(r["psnr_y_enhanced"])) and r["lpips_enhanced"] == ""
    for n in names:
        assert load_image(out / "images" / f"{n}.png").shape == (120, 160, 3)
    # upper bound: the photo of the render's own view, reprojected at the true pose, is the photo
    rc = main(["enhance", str(renders), str(model), "--render-poses", str(poses),
               "--method", "reproject", "--mesh", str(sample_scene / "mesh.glb"),
               "--out", str(tmp_path / "same"), "--gt", str(gt), "--no-lpips", "-q",
               "--allow-same-view"])
    assert rc == 0
    same = _rows(tmp_path / "same" / "metrics.csv")
    assert [Path(r["reference"]).name for r in same] == [Path(f.image_path).name for f in frames]
    for r in same:
        assert float(r["psnr_y_enhanced"]) > float(r["psnr_y_raw"]) + 10.0


@pytest.mark.parametrize("case", ["missing_renders", "missing_weights", "bad_weights",
                                  "reproject_no_mesh", "unnamed_renders", "missing_gt"])
def test_input_errors_exit_2_with_one_line(case, scene_renders, sample_scene, tmp_path, capsys):
    traj = str(sample_scene / "trajectories.txt")
    renders = str(scene_renders)
    extra: list[str] = []
    if case == "missing_renders":
        renders = str(tmp_path / "nope")
    elif case == "missing_weights":
        extra = ["--weights", str(tmp_path / "none.pt")]
    elif case == "bad_weights":
        bad = tmp_path / "bad.pt"
        bad.write_bytes(b"not a checkpoint")
        extra = ["--weights", str(bad)]
    elif case == "reproject_no_mesh":
        extra = ["--method", "reproject"]
    elif case == "unnamed_renders":
        other = tmp_path / "other"
        other.mkdir()
        _save(other / "something.png", np.zeros((8, 8, 3), np.float32))
        renders = str(other)
    elif case == "missing_gt":
        extra = ["--gt", str(tmp_path / "no_gt")]
    rc = main(["enhance", renders, traj, "--out", str(tmp_path / "out"), "-q", *extra])
    err = capsys.readouterr().err
    assert rc == 2
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("pgt-check enhance: error:"), err
    assert not (tmp_path / "out" / "images").exists()


def _frame(fid: str, yaw_deg: float, x: float, image: str = "") -> Frame:
    a = np.radians(yaw_deg)
    m = np.eye(4)
    m[:3, :3] = [[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]]
    m[0, 3] = x
    cam = Camera.pinhole(64, 48, 50, 50, 31.5, 23.5)
    return Frame(fid, cam, m, image, Path(image) if image else None)


def test_nearest_reference_skips_own_photo_and_far_rotations():
    train = [_frame("a", 0, 0.0, "img/a.jpg"), _frame("b", 5, 0.1, "img/b.jpg"),
             _frame("c", 0, 3.0, "img/c.jpg"), _frame("d", 90, 0.0, "img/d.jpg")]
    items = [RenderItem("a", Path("a.png"), train[0]),
             RenderItem("far", Path("far.png"), _frame("far", 180, 0.0)),
             RenderItem("x", Path("x.png"), None)]
    got = nearest_references(items, train)
    assert got[0].reference is train[1]  # not its own photo "a"
    assert got[0].reference_dt == pytest.approx(0.1) and got[0].reference_drot_deg == \
        pytest.approx(5.0)
    assert got[1].reference is None and got[1].status == "no_reference_within_limits"
    assert got[2].reference is None
    # a key two frames share names neither
    idx = frame_index([_frame("1/cam0", 0, 0, "x/f.jpg"), _frame("2/cam0", 0, 1, "y/f.jpg")])
    assert "f" not in idx and set(idx) == {"1/cam0", "2/cam0"}


@pytest.mark.shared_data
@pytest.mark.slow
def test_seven_scenes_three_frames(shared_data, tmp_path, capsys):
    """Three 7-Scenes frames rendered from the TSDF mesh at 213x160, enhanced with the shipped
    weights and the nearest other photo (10 frames away), scored against the photos."""
    root = shared_data / "7scenes_redkitchen"
    traj = read_trajectory(root / "trajectories.txt", sensors=root / "sensors.txt")
    frames = [traj.frames[i] for i in (20, 50, 80)]
    renders = tmp_path / "renders"
    _render_frames(root / "mesh.ply", frames, renders, 1 / 3,
                   [Path(f.image_path).stem for f in frames])
    out = tmp_path / "out"
    rc = main(["enhance", str(renders), str(root / "trajectories.txt"), "--sensors",
               str(root / "sensors.txt"), "--out", str(out), "--gt", str(root / "images"), "-q"])
    assert rc == 0, capsys.readouterr().err
    rows = _rows(out / "metrics.csv")
    assert len(rows) == 3
    for r in rows:
        vals = {k: float(r[k]) for k in METRIC_COLUMNS[2:]}
        assert all(math.isfinite(v) for v in vals.values())
        assert 12.0 < vals["psnr_y_raw"] < 30.0
        # the shipped weights change the render only a little (+0.6 dB on average, model card)
        assert abs(vals["psnr_y_enhanced"] - vals["psnr_y_raw"]) < 4.0
    refs = _rows(out / "references.csv")
    assert all(r["status"] == "ok" and r["reference"] != "" for r in refs)
    assert all(Path(r["reference"]).stem != Path(r["render"]).stem for r in refs)
