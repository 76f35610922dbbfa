from pathlib import Path

import numpy as np
import pytest

from pgt_check.enhance.reference import ReferenceConfig, select_references
from pgt_check.geometry.transforms import axis_angle_to_rotmat, make_rigid
from pgt_check.types import Camera, Frame

CAM = Camera.pinhole(64, 48, 50, 50, 31.5, 23.5)


def _frame(i, x, yaw=0.0, image=True, ts=None):
    pose = make_rigid(axis_angle_to_rotmat(np.array([0, 1.0, 0]), yaw), [x, 0, 0])
    return Frame(str(i), CAM, pose, f"{i}.jpg", Path(f"{i}.jpg") if image else None, ts)


def test_nearest_other_frame_never_self():
    frames = [_frame(0, 0.0), _frame(1, 0.1), _frame(2, 1.0)]
    refs = select_references(frames)
    assert refs["0"].frame_id == "1"
    assert refs["1"].frame_id == "0"
    assert refs["2"].frame_id == "1"
    assert all(refs[f.frame_id].frame_id != f.frame_id for f in frames)


def test_rotation_counts_in_distance_and_limit():
    frames = [_frame(0, 0.0), _frame(1, 0.0, yaw=40.0), _frame(2, 0.5, yaw=0.0)]
    cfg = ReferenceConfig(translation_scale=1.0, rotation_scale_deg=10.0)
    # frame 1: 4.0 cost units away; frame 2: 0.5 away
    assert select_references(frames, cfg)["0"].frame_id == "2"
    cfg2 = ReferenceConfig(translation_scale=1.0, max_rotation_deg=30.0)
    assert select_references(frames, cfg2)["1"].frame_id is None
    assert select_references(frames, cfg2)["1"].reason == "no_reference_within_limits"


def test_count_returns_best_first():
    frames = [_frame(0, 0.0), _frame(1, 0.3), _frame(2, 0.1), _frame(3, 2.0)]
    refs = select_references(frames, ReferenceConfig(count=2))
    assert refs["0"].frame_ids == ("2", "1")
    assert select_references(frames, ReferenceConfig(count=1))["0"].frame_ids == ("2",)


def test_frames_without_image_are_not_references():
    frames = [_frame(0, 0.0), _frame(1, 0.01, image=False), _frame(2, 0.5)]
    assert select_references(frames)["0"].frame_id == "2"


def test_only_eligible_frames_serve_and_positions_keep_their_gap():
    """References among the frames whose own absolute evidence passed (issue 38): a nearer
    frame outside ``eligible`` never serves; the gap counts positions in the whole trajectory,
    and a frame with no eligible one within the limits says so."""
    frames = [_frame(i, 0.01 * i) for i in range(12)]
    eligible = {"0", "1", "2", "9", "10", "11"}
    refs = select_references(frames, ReferenceConfig(count=2, min_frame_gap=2),
                             eligible=eligible)
    assert refs["5"].frame_ids == ("2", "9")  # 3 and 7 are nearer, not eligible
    assert refs["1"].frame_ids == ("9", "10")  # 0 and 2 eligible but within the gap (2)
    assert set(refs["2"].frame_ids) <= eligible
    assert select_references(frames, ReferenceConfig(max_translation=0.02),
                             eligible=eligible)["5"].reason == "no_reference_within_limits"
    assert select_references(frames)["5"].frame_id in {"4", "6"}  # default: every frame


def test_min_frame_gap_skips_adjacent_frames():
    frames = [_frame(i, 0.01 * i) for i in range(30)]
    refs = select_references(frames, ReferenceConfig(min_frame_gap=10))
    assert refs["15"].frame_id in {"5", "25"}
    assert refs["0"].frame_id == "10"


def test_translation_limit_and_modes():
    frames = [_frame(0, 0.0), _frame(1, 5.0)]
    assert select_references(frames, ReferenceConfig(max_translation=1.0))["0"].frame_id is None
    assert select_references(frames, ReferenceConfig(mode="self"))["0"].frame_id == "0"
    none = select_references(frames, ReferenceConfig(mode="none"))
    assert none["0"].frame_id is None and none["0"].reason == "reference_disabled"


def test_time_term():
    frames = [_frame(0, 0.0, ts=0.0), _frame(1, 0.1, ts=100.0), _frame(2, 0.2, ts=1.0)]
    cfg = ReferenceConfig(translation_scale=1.0, time_scale_s=1.0)
    assert select_references(frames, cfg)["0"].frame_id == "2"
    assert select_references(frames, ReferenceConfig(translation_scale=1.0))["0"].frame_id == "1"


@pytest.mark.parametrize("n", [1])
def test_single_frame_has_no_reference(n):
    assert select_references([_frame(0, 0.0)])["0"].frame_id is None
