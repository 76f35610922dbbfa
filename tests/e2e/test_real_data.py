"""End-to-end checks on the shared real datasets (7-Scenes redkitchen, Sceaux castle).

Protocol: the given poses are checked as they are; copies with injected pose errors on a subset
of frames (rotation 1-4 deg about a random axis, translation 5-20 cm, or 2-5 % of the camera
path's span on the castle, whose units are arbitrary) must FAIL; the ROC-AUC of the corner
error against the injected labels must be high. Values measured when the test was written are
stated beside each assertion.
"""

from __future__ import annotations

import numpy as np
import pytest

from pgt_check.io import read_trajectory
from pgt_check.types import Trajectory
from pgt_eval import perturb_trajectory, roc_auc

pytestmark = [pytest.mark.shared_data, pytest.mark.slow]


def _subset(traj: Trajectory, step: int) -> Trajectory:
    return Trajectory(traj.frames[::step], traj.source, traj.format)


def _scores(records, key="corner_error_px"):
    return np.array([np.inf if r[key] is None else r[key] for r in records])


def _labels(records, injected):
    ids = {p.frame_id for p in injected}
    return np.array([r["frame_id"] in ids for r in records])


def test_7scenes_raw_sift(shared_data, check_frames):
    root = shared_data / "7scenes_redkitchen"
    traj = _subset(read_trajectory(root / "trajectories.txt"), 4)  # 25 frames
    mesh = root / "mesh.ply"
    # README: the RGB photos sit ~8-10 px from the depth-camera render on good frames, +-5 px
    # per frame; a threshold of 20 px (2.5 % of the 800 px diagonal) fits that offset.
    # per-frame raw detection only: the run-level checks would (rightly) fail every frame on
    # the poses' shared RGB-vs-depth offset (README "Registration or calibration?")
    cfg = {"verdict": {"threshold_px": 20.0}, "run_checks": {"enabled": False},
           "enhance": {"mode": "never"}}
    good = check_frames(traj, mesh, **cfg)
    verdicts = [r["verdict"] for r in good]
    n_verifiable = len(verdicts) - verdicts.count("UNVERIFIABLE")
    # raw SIFT on blurry TSDF vertex colours: some frames have too few inliers
    assert n_verifiable >= 0.6 * len(verdicts), verdicts
    assert verdicts.count("PASS") >= 0.85 * n_verifiable, verdicts

    bad_traj, injected = perturb_trajectory(traj, 0.4, (1.0, 4.0), (0.05, 0.20), seed=7)
    bad = check_frames(bad_traj, mesh, **cfg)
    labels = _labels(bad, injected)
    auc = roc_auc(_scores(bad), labels)
    assert auc >= 0.8, auc  # measured 0.84 (UNVERIFIABLE good frames count as flagged)
    assert all(r["verdict"] != "PASS" for r, lab in zip(bad, labels, strict=False) if lab)


def test_castle_colourless_mesh_with_reprojection(shared_data, check_frames):
    """The castle mesh has no colour: raw SIFT on the shaded render finds ~5 inliers
    (UNVERIFIABLE on every frame); the reference photo projected through the mesh closes it."""
    root = shared_data / "sceaux_castle"
    traj = read_trajectory(root / "trajectories.txt")
    mesh = root / "mesh.ply"
    enhance = {"enhance": {"mode": "always", "method": "reproject"}}
    good = check_frames(traj, mesh, **enhance)
    assert all(r["shading"] == "shaded" for r in good)
    assert all(r["corner_error_px_raw"] is None for r in good)  # raw path fails everywhere
    verdicts = [r["verdict"] for r in good]
    assert verdicts.count("PASS") == len(good), verdicts  # measured: 10/10, 0.4-1.7 px
    assert all(r["verdict_path"] == "enhanced" for r in good)

    centres = np.array([f.center for f in traj])
    span = float(np.linalg.norm(centres.max(0) - centres.min(0)))
    bad_traj, injected = perturb_trajectory(
        traj, 0.5, (1.0, 4.0), (0.02 * span, 0.05 * span), seed=7
    )
    bad = check_frames(bad_traj, mesh, **enhance)
    labels = _labels(bad, injected)
    assert roc_auc(_scores(bad), labels) >= 0.9  # measured 0.96
    # every injected frame FAILs, or is not verified because the reference that decided it
    # is itself off (measured: one frame, its edge path 29 px against 35.4)
    for r, lab in zip(bad, labels, strict=False):
        if lab:
            assert r["verdict"] == "FAIL" or (
                r["verdict"] == "UNVERIFIABLE" and "fails on its own render" in r["reason"]
            ), r
    # the enhanced error tracks the injected displacement: it does not collapse to identity
    assert min(r["corner_error_px_enhanced"] for r, lab in zip(bad, labels, strict=False) if lab) > 35.4


@pytest.mark.enhance
def test_castle_scene_check_falls_back_to_the_base(shared_data):
    """The castle is unlike every scene MaRINeR was trained on: its shipped decoder scores
    several dB below its own matching-only base there (reports/mariner_scenes.md). The run's
    scene check, on the castle's own photos, sees it and gives the run the base."""
    pytest.importorskip("torch")
    from pgt_check.config import RunConfig
    from pgt_check.measure import FrameChecker, pick_references
    from pgt_check.stages.scene_check import resolve_enhancer_output

    root = shared_data / "sceaux_castle"
    traj = read_trajectory(root / "trajectories.txt")
    cfg = RunConfig.from_dict({"input": {"trajectory": traj.source,
                                         "mesh": str(root / "mesh.ply")},
                               "enhance": {"mode": "always", "method": "mariner"}})
    assert cfg.enhance.output == "auto"
    checker = FrameChecker(cfg, pick_references(traj, traj.frames, cfg))
    try:
        scores = [checker.enhancer.scene_scores(*checker.scene_triple(f)) for f in traj.frames]
        resolved = resolve_enhancer_output(cfg, traj.frames, checker.references, checker)
    finally:
        checker.close()
    # the decoder is below the base on most castle frames, and the run gets the base
    assert sum(m < b for m, b in scores) >= 0.7 * len(scores)
    assert resolved.enhance.output == "base" and checker.enhancer.output == "base"


@pytest.mark.enhance
def test_castle_mariner_path_is_absolute_evidence(shared_data, check_frames):
    """The colourless castle (never trained on) with the shipped MaRINeR weights, matched at the
    size the output is made at (160 px short side): the enhanced path alone meets issue 37's
    evidence targets on this scene where raw matching finds nothing: >= 60 % of the given frames
    verified, a trajectory moved by 2 deg + 4 % flagged on >= 90 % of its frames, and the
    enhanced corner error separates given from moved frames with ROC-AUC >= 0.9: the output keeps
    the render's geometry (reference content is placed where it matches the render's content;
    the reference's pose is never used), so a moved render is measured as moved. Measured: 9/10 given, 9/10 moved flagged, AUC 0.97 (the 7-Scenes-only
    weights shipped before: 4/10, 10/10, 0.77; reports/mariner_training.md, ninth session)."""
    pytest.importorskip("torch")
    from pgt_eval import move_trajectory, roc_auc, shared_transform

    root = shared_data / "sceaux_castle"
    traj = read_trajectory(root / "trajectories.txt")
    mesh = root / "mesh.ply"
    cfg = {"enhance": {"mode": "always", "method": "mariner"}, "edges": {"mode": "never"},
           "run_checks": {"enabled": False}}
    centres = np.array([f.center for f in traj])
    span = float(np.linalg.norm(centres.max(0) - centres.min(0)))
    moved = move_trajectory(traj, shared_transform(traj, 2.0, 0.04 * span, seed=1))

    def errors(records) -> np.ndarray:
        return np.array([np.inf if r["corner_error_px_enhanced"] is None
                         else r["corner_error_px_enhanced"] for r in records])

    given = check_frames(traj, mesh, **cfg)
    assert all(r["corner_error_px_raw"] is None for r in given)  # raw matching: nothing
    moved_records = check_frames(moved, mesh, **cfg)
    thr = np.array([r["threshold_px"] for r in given + moved_records])
    g, m = errors(given), errors(moved_records)
    assert np.sum(g <= thr[: len(g)]) >= 0.6 * len(g)  # verified; measured 9 of 10
    assert np.sum(m > thr[len(g):]) >= 0.9 * len(m)  # flagged; measured 9 of 10
    auc = roc_auc(np.r_[g, m], np.r_[np.zeros(len(g)), np.ones(len(m))])
    assert auc >= 0.9, auc  # measured 0.97
