"""Second audit (#25): reference selection is near-linear in the trajectory (it was quadratic,
also with ``--limit 1``) and makes exactly the choices of scoring every frame."""

from __future__ import annotations

import time

import numpy as np
import pytest

from pgt_check.config import ReferenceConfig
from pgt_check.enhance.reference import _angles_deg, select_references
from pgt_check.geometry.transforms import axis_angle_to_rotmat
from pgt_check.types import Camera, Frame


def _brute(frames, config):
    """The rule as it was implemented before (every frame scored against every frame)."""
    n = len(frames)
    centres = np.array([f.world_from_cam[:3, 3] for f in frames])
    rotations = np.array([f.world_from_cam[:3, :3] for f in frames])
    has_image = np.array([f.image_file is not None for f in frames])
    stamps = np.array([np.nan if f.timestamp is None else float(f.timestamp) for f in frames])
    t_scale = config.translation_scale
    if t_scale is None:
        extent = float(np.linalg.norm(centres.max(0) - centres.min(0))) if n > 1 else 0.0
        t_scale = max(0.1 * extent, 1e-9)
    idx = np.arange(n)
    out = {}
    for i, f in enumerate(frames):
        dt = np.linalg.norm(centres - centres[i], axis=1)
        dr = _angles_deg(rotations, rotations[i])
        cost = dt / t_scale + dr / config.rotation_scale_deg
        if config.time_scale_s is not None and np.isfinite(stamps[i]):
            dtime = np.abs(stamps - stamps[i])
            cost = cost + np.where(np.isfinite(dtime), dtime / config.time_scale_s, 0.0)
        ok = has_image & (np.abs(idx - i) >= max(1, config.min_frame_gap))
        ok &= dr <= config.max_rotation_deg
        if config.max_translation is not None:
            ok &= dt <= config.max_translation
        cand = np.flatnonzero(ok)
        best = cand[np.argsort(cost[cand], kind="stable")[: max(1, config.count)]]
        out[f.frame_id] = tuple(frames[int(k)].frame_id for k in best)
    return out


_CAM = Camera.pinhole(64, 48, 50, 50, 32, 24)


def _trajectory(n, seed, *, grid=False, video=True):
    rng = np.random.default_rng(seed)
    frames = []
    for i in range(n):
        if grid:  # many equal distances and costs: the tie-break decides
            c = np.array([i % 5, (i // 5) % 3, 0.0])
            r = axis_angle_to_rotmat([0, 0, 1], 90.0 * (i % 4))
        elif video:
            c = np.array([np.cos(i / 20), np.sin(i / 20), 0.01 * i]) + rng.normal(0, 0.01, 3)
            r = axis_angle_to_rotmat(rng.normal(size=3), rng.uniform(0, 40))
        else:
            c = rng.uniform(-5, 5, 3)
            r = axis_angle_to_rotmat(rng.normal(size=3), rng.uniform(0, 180))
        m = np.eye(4)
        m[:3, :3], m[:3, 3] = r, c
        image = None if rng.random() < 0.1 else f"{i}.png"
        frames.append(Frame(str(i), _CAM, m, image, image, float(i)))
    return frames


@pytest.mark.parametrize("kind", ["video", "random", "grid"])
@pytest.mark.parametrize("config", [
    ReferenceConfig(),
    ReferenceConfig(count=3, min_frame_gap=5),
    ReferenceConfig(max_translation=0.5, max_rotation_deg=20),
    ReferenceConfig(time_scale_s=10.0, translation_scale=0.3),
    ReferenceConfig(count=2, min_frame_gap=40, rotation_scale_deg=1.0),
])
def test_same_choices_as_scoring_every_frame(kind, config):
    frames = _trajectory(300, 7, grid=kind == "grid", video=kind == "video")
    got = select_references(frames, config)
    want = _brute(frames, config)
    assert {k: v.frame_ids for k, v in got.items()} == want


def test_only_the_checked_frames_are_selected():
    frames = _trajectory(200, 1)
    got = select_references(frames, ReferenceConfig(), only=["5", "17"])
    assert set(got) == {"5", "17"}
    assert got["5"].frame_ids == _brute(frames, ReferenceConfig())["5"]


def test_near_linear(case):
    """10,000 poses: all frames in a few seconds (was ~22 s), one frame (--limit 1) at once."""
    frames = _trajectory(10_000, 3)
    t0 = time.perf_counter()
    select_references(frames, ReferenceConfig(), only=["0"])
    one = time.perf_counter() - t0
    t0 = time.perf_counter()
    select_references(frames, ReferenceConfig())
    every = time.perf_counter() - t0
    case("reference selection, 10,000 poses", "near-linear",
         f"one frame {one:.2f} s, every frame {every:.1f} s")
    assert one < 1.0 and every < 10.0
