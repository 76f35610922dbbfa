"""Pose writers: what they write reads back to the same poses in each format."""

from __future__ import annotations

import numpy as np

from pgt_check.io import read_trajectory
from pgt_check.io.writers import colmap_images_text, write_trajectory_file
from pgt_check.types import Trajectory
from pgt_eval import perturb_trajectory


def _same_poses(a: Trajectory, b: Trajectory, ids=None) -> None:
    pa, pb = a.by_id(), b.by_id()
    for fid in ids or pa:
        np.testing.assert_allclose(pa[fid].world_from_cam, pb[fid].world_from_cam, atol=1e-12)


def test_lamar_round_trip_keeps_ids_and_poses(tmp_path, sample_scene):
    traj = read_trajectory(sample_scene / "trajectories.txt")
    moved, injected = perturb_trajectory(traj, 0.5, (1.0, 3.0), (0.05, 0.1), seed=3)
    assert injected
    assert write_trajectory_file(moved, tmp_path / "corrected_trajectory.txt") == "lamar"
    back = read_trajectory(tmp_path / "corrected_trajectory.txt", "lamar",
                           sensors=sample_scene / "sensors.txt",
                           images=sample_scene / "images.txt")
    assert [f.frame_id for f in back] == [f.frame_id for f in moved]
    _same_poses(moved, back)


def test_tum_round_trip(tmp_path, sample_scene):
    lamar = read_trajectory(sample_scene / "trajectories.txt")
    src = tmp_path / "traj_tum.txt"
    # a TUM input: the sample's poses with the frames' integer timestamps as TUM timestamps
    rows = [f"{int(f.timestamp)} " + " ".join(repr(float(v)) for v in f.world_from_cam[:3, 3]) + " 0 0 0 1"
            for f in lamar]
    src.write_text("\n".join(rows) + "\n")
    cam = "PINHOLE,64,48,50,50,32,24"
    (tmp_path / "images").mkdir()
    for f in lamar:
        (tmp_path / "images" / f"{int(f.timestamp)}.png").write_bytes(b"")
    tum = read_trajectory(src, "tum", camera=cam)
    moved, _ = perturb_trajectory(tum, 1.0, (2.0, 4.0), (0.1, 0.2), seed=1)
    out = tmp_path / "out" / "corrected.txt"
    assert write_trajectory_file(moved, out) == "tum"
    back = read_trajectory(out, "tum", camera=cam, images=tmp_path / "images")
    _same_poses(moved, back)


def test_colmap_images_txt_round_trip(tmp_path, sample_scene):
    lamar = read_trajectory(sample_scene / "trajectories.txt")
    model = tmp_path / "sparse"
    model.mkdir()
    cam = lamar[0].camera
    params = " ".join(repr(float(v)) for v in cam.to_colmap_params())
    (model / "cameras.txt").write_text(f"1 {cam.model} {cam.width} {cam.height} {params}\n")
    (model / "points3D.txt").write_text("")
    named = Trajectory(tuple(f.with_pose(f.world_from_cam) for f in lamar), format="colmap")
    # image ids 7, 8, ... (not 1..n): the writer must keep a model's own ids
    ids = {f.image_path: 7 + i for i, f in enumerate(lamar)}
    (model / "images.txt").write_text(colmap_images_text(named, ids, {n: 1 for n in ids}))
    traj = read_trajectory(model, images=sample_scene)
    moved, _ = perturb_trajectory(traj, 1.0, (2.0, 4.0), (0.1, 0.2), seed=2)
    out = tmp_path / "fixed"
    out.mkdir()
    assert write_trajectory_file(moved, out / "images.txt") == "colmap"
    text = (out / "images.txt").read_text()
    first = next(line for line in text.splitlines() if line and not line.startswith("#"))
    assert int(first.split()[0]) == ids[moved[0].frame_id]  # ids come from the model
    for name in ("cameras.txt", "points3D.txt"):
        (out / name).write_text((model / name).read_text())
    back = read_trajectory(out, images=sample_scene)
    _same_poses(moved, back)
