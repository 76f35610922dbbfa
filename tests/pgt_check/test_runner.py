import numpy as np
import pytest

from pgt_check.config import RunConfig
from pgt_check.io import read_trajectory
from pgt_check.io.photo import prepare_photo
from pgt_check.measure import EnhanceWhy, FrameChecker, PathResult, pick_references
from pgt_check.types import Camera


def _path(success=True, inliers=100, err=2.0, reason=""):
    z = np.zeros((0, 2))
    return PathResult(inliers, inliers, 1.0, reason, np.eye(3) if success else None,
                      err if success else None, z, z, np.zeros(0, bool), 0, 0, 0.0, 0.0)


@pytest.mark.parametrize(
    "path,expected",
    [
        (_path(), (EnhanceWhy.RAW_DECISIVE, "")),
        (_path(err=40.0), (EnhanceWhy.RAW_DECISIVE, "")),
        (_path(success=False, reason="too_few_inliers"),
         (EnhanceWhy.RAW_FAILED, "too_few_inliers")),
        (_path(inliers=10), (EnhanceWhy.RAW_FEW_INLIERS, "")),
        (_path(err=12.0), (EnhanceWhy.RAW_NEAR_THRESHOLD, "")),
        (_path(err=23.0), (EnhanceWhy.RAW_NEAR_THRESHOLD, "")),
    ],
)
def test_auto_policy(path, expected):
    checker = FrameChecker(RunConfig.from_dict({"enhance": {"mode": "auto"}}))
    assert checker._enhance_decision(path, threshold=16.0) == expected


def test_never_and_always():
    never = FrameChecker(RunConfig.from_dict({"enhance": {"mode": "never"}}))
    assert never._enhance_decision(_path(), 16.0) == (EnhanceWhy.MODE_NEVER, "")
    assert RunConfig().enhance.mode == "auto"  # the default
    always = FrameChecker(RunConfig.from_dict({"enhance": {"mode": "always"}}))
    assert always._enhance_decision(_path(), 16.0) == (EnhanceWhy.MODE_ALWAYS, "")


def test_prepare_photo_scales_camera_for_resized_images():
    cam = Camera.pinhole(640, 480, 500, 500, 319.5, 239.5)
    img = np.zeros((240, 320, 3), np.float32)
    out, c = prepare_photo(img, cam)
    assert (c.width, c.height) == (320, 240) and c.focal == pytest.approx((250, 250))
    from pgt_check.errors import InputError

    with pytest.raises(InputError, match="does not match"):
        prepare_photo(np.zeros((100, 320, 3), np.float32), cam)


def _measure_sample(sample_scene, **enhance):
    traj = read_trajectory(sample_scene / "trajectories.txt")
    cfg = RunConfig.from_dict(
        {"input": {"trajectory": str(sample_scene / "trajectories.txt"),
                   "mesh": str(sample_scene / "mesh.glb")}, "enhance": enhance}
    )
    checker = FrameChecker(cfg, pick_references(traj, traj.frames, cfg))
    try:
        return {f.frame_id: checker.measure(f).row() for f in traj.frames}
    finally:
        checker.close()


def _perturbed_ids(sample_scene):
    return [ln.split(",")[0] for ln in (sample_scene / "perturbed.txt").read_text().splitlines()
            if ln and not ln.startswith("#")]


def test_enhanced_error_tracks_injected_displacement(sample_scene):
    """The enhanced image must keep the render's geometry: on the perturbed frames its corner
    error stays close to the raw one (no collapse toward the reference / identity)."""
    recs = _measure_sample(sample_scene, mode="always", method="reproject")
    for fid in _perturbed_ids(sample_scene):
        r = recs[fid]
        assert r["enhanced"] and r["reference_id"] not in (None, fid)
        raw, enh = r["corner_error_px_raw"], r["corner_error_px_enhanced"]
        assert enh == pytest.approx(raw, rel=0.3), (fid, raw, enh)
        assert enh > 10.0
        assert r["pose_drot_deg"] is not None


def test_auto_skips_decisive_frames(sample_scene):
    recs = _measure_sample(sample_scene, mode="auto", method="reproject")
    skipped = [r for r in recs.values() if not r["enhanced"]]
    # the sample scene's raw results are decisive: most frames need no enhancement
    assert len(skipped) >= 0.7 * len(recs)
    assert all(r["enhanced_why"] == "raw_decisive" for r in skipped)
    assert all(r["corner_error_px_enhanced"] is None for r in skipped)


@pytest.mark.enhance
def test_mariner_path_wiring_with_random_weights(sample_scene, tmp_path):
    """Wiring only: a RANDOMLY INITIALISED small model (not the shipped weights) must give
    finite enhanced-path fields of the right kind."""
    torch = pytest.importorskip("torch")
    from mariner_core.config import MarinerConfig
    from mariner_core.enhancer import save_checkpoint
    from mariner_core.model import Mariner

    torch.manual_seed(0)
    model = Mariner(MarinerConfig(channels=8, encoder_blocks=(1, 1, 1), decoder_blocks=(1, 1, 1)))
    path = tmp_path / "random.pt"
    save_checkpoint(model, path)
    traj = read_trajectory(sample_scene / "trajectories.txt")
    cfg = RunConfig.from_dict(
        {"input": {"trajectory": str(sample_scene / "trajectories.txt"),
                   "mesh": str(sample_scene / "mesh.glb")},
         "enhance": {"mode": "always", "method": "mariner", "weights": str(path),
                     "reference": {"count": 1}}}
    )
    checker = FrameChecker(cfg, pick_references(traj, traj.frames, cfg))
    rec = checker.measure(traj.frames[0]).row()
    checker.close()
    assert rec["error"] == "", rec["error_detail"]
    assert rec["enhanced"] and rec["t_enhance_s"] > 0
    assert rec["n_matches_enhanced"] is not None
