"""Errors that neighbouring frames share, end to end through the CLI (issue #13), and the
geometric-edge path on a textureless scene (issue #17).

The trajectory is perturbed the way real pseudo-ground truth fails (the whole trajectory, not
one frame among clean ones), written as a LaMAR trajectory beside the original images, and
checked with the default settings."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from pgt_check.cli import main
from pgt_check.geometry.transforms import pose_difference
from pgt_check.io import read_trajectory, write_lamar
from pgt_check.types import Trajectory
from pgt_eval import move_trajectory, shared_transform, textureless_scene


def _run(traj: Trajectory, mesh: Path, tmp: Path, *extra: str) -> tuple[int, dict, list]:
    import csv

    write_lamar(traj, tmp / "in")
    rc = main([str(tmp / "in" / "trajectories.txt"), "--mesh", str(mesh), "--out",
               str(tmp / "out"), "--report-details", "0", "-q", *extra])
    summary = json.loads((tmp / "out" / "summary.json").read_text())
    with open(tmp / "out" / "frames.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    return rc, summary, rows


def _flagged(rows) -> float:
    return float(np.mean([r["verdict"] != "PASS" for r in rows]))


def _real(shared_data: Path, dataset: str) -> tuple[Path, float, tuple[str, ...], Trajectory]:
    """(root, median scene depth, extra CLI options, trajectory) of a shared dataset: the
    castle's 10 photos, or 20 7-Scenes frames (every 5th), judged after removing their real
    RGB-vs-depth calibration offset as the README documents for that data."""
    if dataset == "castle":
        root = shared_data / "sceaux_castle"
        return root, 9.0, (), read_trajectory(root / "trajectories.txt")
    root = shared_data / "7scenes_redkitchen"
    full = read_trajectory(root / "trajectories.txt")
    traj = Trajectory(tuple(full.frames[::5]), full.source, full.format)
    return root, 2.3, ("--remove-calibration",), traj


@pytest.fixture(scope="module")
def boxes(tmp_path_factory):
    return textureless_scene(tmp_path_factory.mktemp("boxes"), 16)


def test_textureless_scene_is_verified_by_edges(boxes, tmp_path, capsys):
    """No texture at all: raw features find nothing; the edge path verifies >= 80 %."""
    traj, mesh = boxes
    rc, summary, rows = _run(traj, mesh, tmp_path)
    assert np.mean([r["verdict"] == "PASS" for r in rows]) >= 0.8, [r["reason"] for r in rows]
    assert all(r["corner_error_px_edges"] for r in rows)
    assert summary["shared_errors"]["registration"]["status"] == "passed"


def test_textureless_misregistered_trajectory_is_flagged(boxes, tmp_path, capsys):
    traj, mesh = boxes
    moved = move_trajectory(traj, shared_transform(traj, 1.0, 0.0, seed=1))
    rc, summary, rows = _run(moved, mesh, tmp_path, "--registration-rounds", "8")
    reg = summary["shared_errors"]["registration"]
    assert rc == 1 and reg["status"] == "failed"
    assert reg["angle_deg"] == pytest.approx(1.0, rel=0.3)
    assert _flagged(rows) >= 0.9
    assert "registration" in capsys.readouterr().out  # the CLI states the finding
    # the estimate was refined at the corrected poses, and the registered trajectory written
    rounds = reg["refinement"]["rounds"]
    assert rounds and rounds[-1]["effect_px"] < reg["effect_px"] / 4
    registered = read_trajectory(tmp_path / "out" / "registered_trajectory.txt", "lamar",
                                 sensors=tmp_path / "in" / "sensors.txt",
                                 images=tmp_path / "in" / "images.txt")
    off = [pose_difference(r.world_from_cam, t.world_from_cam)[1]
           for r, t in zip(registered.frames, traj.frames, strict=True)]
    assert np.median(off) < 0.3  # degrees; the moved trajectory is 1 deg off
    # `pgt-check report` rebuilds the same refined estimate from the stored refinement
    assert main(["report", str(tmp_path / "out")]) == 1
    again = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert again["shared_errors"]["registration"]["angle_deg"] == reg["angle_deg"]


def test_many_wrong_frames_leave_the_correct_ones_alone(tmp_path_factory, capsys):
    """Issue 38: 24 frames of the textureless scene, 40 % of them with errors of their own
    (0.5-4 deg, 1-8 % of the 4 m depth, random directions; wrong neighbours too), checked with
    ``--remove-calibration``: the run-level checks leave those frames out (and say so), the
    registration is not failed by them, and the correct frames are not failed by a shared
    finding that exists only because of the wrong ones."""
    from pgt_eval import perturb_trajectory

    traj, mesh = textureless_scene(tmp_path_factory.mktemp("boxes24"), 24)
    wrong_traj, injected = perturb_trajectory(traj, 0.4, (0.5, 4.0), (0.04, 0.32), seed=4)
    wrong = {p.frame_id for p in injected}
    tmp = tmp_path_factory.mktemp("run")
    rc, summary, rows = _run(wrong_traj, mesh, tmp, "--remove-calibration")
    se = summary["shared_errors"]
    assert se["registration"]["status"] != "failed", se["registration"]["message"]
    assert se["drift"]["status"] != "failed", se["drift"]["message"]
    screen = se["frame_screen"]
    left = {f["frame_id"] for f in screen["left_out"]}
    assert screen["n_left_out"] == len(left) >= 0.5 * len(wrong)
    assert len(left - wrong) <= 2  # the correct frames are kept
    assert screen["cut"] == pytest.approx(screen["inflation"] * screen["chi2_quantile"], rel=1e-6)
    correct = [r for r in rows if r["frame_id"] not in wrong]
    assert not any(r["reason"].startswith(("registration", "drift")) for r in correct)
    assert np.mean([r["verdict"] == "PASS" for r in correct]) >= 0.8, [r["reason"] for r in correct]
    assert "left out of the pooled fits" in capsys.readouterr().out  # the CLI says so


@pytest.mark.slow
def test_sample_scene_moved_trajectory(sample_scene, tmp_path, capsys):
    traj = read_trajectory(sample_scene / "trajectories.txt")
    depth = 3.0  # the sample room: cameras 2-4 m from the walls
    moved = move_trajectory(traj, shared_transform(traj, 2.0, 0.04 * depth, seed=2))
    rc, summary, rows = _run(moved, sample_scene / "mesh.glb", tmp_path)
    reg = summary["shared_errors"]["registration"]
    assert rc == 1 and reg["status"] == "failed", reg["message"]
    assert reg["angle_deg"] == pytest.approx(2.0, rel=0.3)
    assert _flagged(rows) >= 0.9


@pytest.mark.shared_data
@pytest.mark.slow
@pytest.mark.parametrize(
    ("dataset", "deg", "frac"),
    # the castle takes the rotation and the translation apart (the registered trajectory's
    # re-check with the translation); both together on 7-Scenes (a castle copy of that case
    # cost CI ~1 min for nothing more). 7-Scenes was an xfail (#38): its refined translation
    # came out 0.048-0.065 of 0.092, passing or not from run to run; the wall-clock budget had
    # stopped the rounds early. Unbounded (2026-12-04): 5 rounds, converged, 2.29 deg and
    # 0.089 of 2.0 and 0.092
    [("castle", 1.0, 0.0), ("castle", 0.0, 0.04), ("7scenes", 2.0, 0.04)],
)
def test_real_moved_trajectory_fails_the_gate(shared_data, dataset, deg, frac, tmp_path, capsys):
    """2 deg + 4 % of the depth on 7-Scenes, 1 deg and 4 % alone on the castle: the
    gate fails, the summary states the correction, and with ``--registration-rounds 8`` (the
    failed check's estimate refined by measuring again at the corrected poses) it recovers the
    injected rotation and translation within 30 %. The 7-Scenes poses also carry their real
    RGB-vs-depth offset, which these sweep views cannot tell from a world rotation; as the
    README documents for that data, the calibration is estimated once on a trusted run (the
    given poses) and removed from the moved one (``--calibration-from``)."""
    root, depth, extra, traj = _real(shared_data, dataset)
    if dataset == "7scenes":
        _, trusted, _ = _run(traj, root / "mesh.ply", tmp_path / "trusted", *extra)
        assert trusted["shared_errors"]["registration"]["status"] == "passed"
        # the mesh was coloured with these (depth-camera) poses: its colours sit off its
        # geometry by the RGB-vs-depth offset (README: the edges see ~8 px, texture ~0)
        tex = trusted["shared_errors"]["texture"]
        assert tex["status"] == "finding" and 4.0 < tex["effect_px"] < 11.0, tex
        extra = ("--calibration-from", str(tmp_path / "trusted" / "out" / "summary.json"))
    moved = move_trajectory(traj, shared_transform(traj, deg, frac * depth, seed=1))
    # no wall-clock bound on the rounds (``correct.budget`` 0): with the default bound a
    # loaded machine stopped them after one round (castle 2 deg + 4 %: "1 round(s) took
    # 32.6 s of the 27.4 s budget", translation 0.20 of 0.36); the bound has its own test
    unbounded = tmp_path / "unbounded.toml"
    unbounded.write_text("[correct]\nbudget = 0\n")
    rc, summary, rows = _run(moved, root / "mesh.ply", tmp_path / "moved", *extra,
                             "--registration-rounds", "8", "--config", str(unbounded))
    reg = summary["shared_errors"]["registration"]
    assert rc == 1 and reg["status"] == "failed", reg["message"]
    # rotation about the camera centroid and translation move these alike views (one facade,
    # one kitchen sweep) almost alike: one fit on evidence measured at the moved poses splits
    # them wrongly (castle 4 %: 1.5-2.2 deg + 0.10-0.18 units for 0 deg + 0.36); the rounds
    # at the corrected poses recover the split
    assert reg["refinement"]["rounds"], reg["message"]
    if deg:
        assert reg["angle_deg"] == pytest.approx(deg, rel=0.3)
    else:
        assert reg["angle_deg"] < 1.0  # no rotation injected; 4 % is ~2.3 deg of image motion
    if frac:
        assert reg["translation"] == pytest.approx(frac * depth, rel=0.3)
    assert reg["corrected_world_from_world"] is not None
    assert _flagged(rows) >= 0.9
    if dataset == "castle":  # colourless mesh: no texture evidence to compare
        assert "texture" not in summary["shared_errors"]
    if dataset == "castle" and not deg:
        # the registered trajectory the run wrote passes the registration check
        moved_in = tmp_path / "moved" / "in"
        registered = read_trajectory(
            tmp_path / "moved" / "out" / "registered_trajectory.txt", "lamar",
            sensors=moved_in / "sensors.txt", images=moved_in / "images.txt",
        )
        rc2, again, _ = _run(registered, root / "mesh.ply", tmp_path / "registered", *extra)
        # every frame PASSes again, and what is left of the shared error is a tenth of what
        # was injected at most; the check itself may call it inconclusive (on a fresh machine
        # of 2026-12-04: 4.6 px, 95 % 3.1-6.0, against the 5.3 px threshold), never failed
        reg2 = again["shared_errors"]["registration"]
        assert rc2 == 0 and reg2["status"] in ("passed", "inconclusive"), reg2["message"]
        assert reg2["effect_px"] < 0.1 * reg["effect_px"], (reg2["message"], reg["message"])


@pytest.mark.shared_data
@pytest.mark.slow
# castle only: on 20 sparse 7-Scenes frames the largest drift window is 6.25 px (95 % 4.32-8.17),
# its lower bound below the 4.8 px drift threshold (windows grow long to hold enough inliers and
# average the drift). That case was a non-strict xfail, which passes whatever happens (and cost
# CI ~30 s); 7-Scenes drift is measured by benchmarks/scenes_loso.py on 30 frames instead
# (flagged 10-12/12 there, reports/scenes_loso.md)
@pytest.mark.parametrize("dataset", ["castle"])
def test_real_drifting_segment_is_separated(shared_data, dataset, tmp_path, capsys):
    """The last 40 % of the frames drift to 2 deg + 4 % of the depth (neighbours share the
    error, so the reprojected references cannot see it): the drift check separates the
    drifting frames by their drift score, covers the ones without evidence of their own, and
    none of them PASSes."""
    from pgt_eval import drift_trajectory, roc_auc

    root, depth, extra, traj = _real(shared_data, dataset)
    drifted, ids = drift_trajectory(traj, 0.6, 2.0, 0.04 * depth, seed=2)
    rc, summary, rows = _run(drifted, root / "mesh.ply", tmp_path, *extra)
    drift = summary["shared_errors"]["drift"]
    assert rc == 1 and drift["status"] == "failed", drift["message"]
    labels = np.array([r["frame_id"] in set(ids) for r in rows])
    score = np.array([float(r["drift_px"]) if r["drift_px"] else 0.0 for r in rows])
    assert roc_auc(score, labels) >= 0.95  # measured 1.00 on both
    drifting = [r for r, lab in zip(rows, labels, strict=True) if lab]
    # the frames where the drift has grown past half its final size are never PASS
    assert all(r["verdict"] != "PASS" for r in drifting[len(drifting) // 2 :])
    assert all(r["drift_px"] for r in drifting)  # every drifting frame is scored
