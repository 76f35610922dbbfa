"""The run-level checks as plug-ins (``verdict/checks/``): the registry holds every check module
once, each module's protocol (KEY, TITLE, run, lines, table), the shared ``CheckContext`` on
synthetic absolute evidence (a mesh point seen by the render at the checked pose, observed by the
photo at the true pose: no rendering), and the default presentations in ``checks/base.py``.
The checks' decisions on harder runs are tested through ``judge_run`` in
``tests/pgt_check/verdict/test_shared.py``."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import pgt_check.verdict.checks as checks_pkg
from pgt_check.config import RunConfig
from pgt_check.enhance.base import Evidence
from pgt_check.measure import AbsoluteEvidence, FrameMeasurement, PathMeasurement
from pgt_check.types import Camera, Frame, Trajectory
from pgt_check.verdict.checks import CHECKS, CheckContext
from pgt_check.verdict.checks.base import (
    camera_lines,
    camera_rows,
    frame_residuals,
    single_row,
    status_lines,
)
from pgt_check.verdict.shared import frame_evidence, run_shared_checks, shared_threshold
from pgt_eval import move_trajectory, shared_transform

CAM = Camera.pinhole(640, 480, 500.0, 500.0, 319.5, 239.5)


def _trajectory(n: int = 24) -> Trajectory:
    frames = []
    for i in range(n):
        a = 2 * np.pi * i / n
        eye = np.array([3.0 * np.cos(a), 3.0 * np.sin(a), 1.5])
        z = np.array([0, 0, 0.8]) - eye
        z /= np.linalg.norm(z)
        x = np.cross(z, [0, 0, 1.0])
        x /= np.linalg.norm(x)
        m = np.eye(4)
        m[:3, :3] = np.stack([x, np.cross(z, x), z], axis=1)
        m[:3, 3] = eye
        frames.append(Frame(f"f{i:03d}", CAM, m, timestamp=float(i)))
    return Trajectory(tuple(frames), "synthetic", "lamar")


def _measurements(true: Trajectory, checked: Trajectory) -> list[FrameMeasurement]:
    rng = np.random.default_rng(0)
    world = rng.uniform([-1.5, -1.5, 0.0], [1.5, 1.5, 1.6], size=(300, 3))
    out = []
    for t, c in zip(true.frames, checked.frames, strict=True):
        x_true = world @ t.cam_from_world[:3, :3].T + t.cam_from_world[:3, 3]
        x_chk = world @ c.cam_from_world[:3, :3].T + c.cam_from_world[:3, 3]
        uv = x_true[:, :2] / x_true[:, 2:3] * 500.0 + [319.5, 239.5]
        ok = (x_true[:, 2] > 0.1) & (uv >= 0).all(1) & (uv < [640, 480]).all(1)
        idx = np.flatnonzero(ok)[:50]
        uv = uv[idx] + rng.normal(0, 0.5, (len(idx), 2))
        err = float(np.median(np.linalg.norm(
            x_chk[idx, :2] / x_chk[idx, 2:3] * 500.0 + [319.5, 239.5] - uv, axis=1)))
        raw = PathMeasurement(
            kind="raw", method="render", evidence=Evidence.ABSOLUTE, n_kpts_render=500,
            n_kpts_photo=500, n_matches=200, n_inliers=120, inlier_ratio=0.6, reason="",
            photo_from_render=tuple(map(tuple, np.eye(3))), corner_error_px=err,
        )
        out.append(FrameMeasurement(
            frame_id=c.frame_id, timestamp=c.timestamp, image_path=None, width=640, height=480,
            center=tuple(c.center), coverage=0.9, raw=raw, enhanced=None, verdict_path="raw",
            world_from_cam=tuple(map(tuple, c.world_from_cam)),
            intrinsics=(500.0, 500.0, 319.5, 239.5), camera_id="cam0",
            evidence=AbsoluteEvidence(("raw",), tuple(map(tuple, uv)),
                                      tuple(map(tuple, x_chk[idx]))),
        ))
    return out


def _context(ms: list[FrameMeasurement], config: RunConfig) -> CheckContext:
    thr = shared_threshold(ms, config)
    frame_thr = float(np.median([config.verdict.threshold_for(640, 480) for _ in ms]))
    return CheckContext(ms, config, thr, frame_thr, frame_evidence(ms))


@pytest.fixture(scope="module")
def truth() -> Trajectory:
    return _trajectory()


@pytest.fixture(scope="module")
def correct(truth) -> list[FrameMeasurement]:
    return _measurements(truth, truth)


@pytest.fixture(scope="module")
def misregistered(truth) -> list[FrameMeasurement]:
    moved = move_trajectory(truth, shared_transform(truth, 2.0, 0.12, seed=4))
    return _measurements(truth, moved)


def test_the_registry_holds_every_check_module_once_with_its_protocol():
    folder = Path(checks_pkg.__file__).parent
    modules = {p.stem for p in folder.glob("*.py")} - {"__init__", "base"}
    registered = [c.__name__.rsplit(".", 1)[-1] for c in CHECKS]
    assert sorted(registered) == sorted(modules)
    keys = [c.KEY for c in CHECKS]
    assert len(set(keys)) == len(keys)
    for c in CHECKS:
        assert isinstance(c.TITLE, str) and c.TITLE
        assert callable(c.run) and callable(c.lines) and callable(c.table)


def test_the_checks_run_on_a_context_as_run_shared_checks_runs_them(correct):
    config = RunConfig()
    ctx = _context(correct, config)
    entries = {c.KEY: e for c in CHECKS if (e := c.run(ctx)) is not None}
    shared = run_shared_checks(correct, config)
    assert set(entries) == set(shared.entries)
    for key, entry in entries.items():
        assert entry.to_json() == shared.entries[key].to_json(), key
    # without --calibration-from there is no calibration change entry
    assert "calibration_change" not in entries


def test_a_correct_run_passes_and_prints_nothing(correct):
    ctx = _context(correct, RunConfig())
    by_key = {c.KEY: c for c in CHECKS}
    for key in ("registration", "similarity", "drift"):
        check = by_key[key]
        summary = check.run(ctx).to_json()
        assert summary["status"] == "passed", (key, summary.get("message"))
        assert check.lines(summary) == []
        assert check.table(summary) == [(check.TITLE, summary)]
    assert ctx.left_out == () and ctx.pooled == ctx.ev
    assert ctx.outside_drift is None
    assert float(np.max(frame_residuals(ctx.ev, _Identity()))) < 3.0


def test_a_misregistered_run_fails_registration_and_prints_its_message(misregistered):
    ctx = _context(misregistered, RunConfig())
    by_key = {c.KEY: c for c in CHECKS}
    summary = by_key["registration"].run(ctx).to_json()
    assert summary["status"] == "failed"
    assert by_key["registration"].lines(summary) == [summary["message"]]
    calibration = by_key["calibration"].run(ctx).to_json()
    assert set(calibration) == {"cam0"}
    rows = by_key["calibration"].table(calibration)
    assert [name for name, _ in rows] == ["calibration (camera cam0)"]


class _Identity:
    """A failed registration estimate: ``frame_residuals`` measures the poses as they are."""

    success = False
    corrected_world_from_world = None


def test_the_default_presentations_read_the_summary_entry_back():
    failed = {"status": "failed", "message": "registration off by 3 px"}
    passed = {"status": "passed", "message": "fine"}
    no_evidence = {"status": "not_checked", "reason": "no_geometric_evidence", "message": "blind"}
    assert status_lines(failed) == ["registration off by 3 px"]
    assert status_lines(passed) == []
    assert status_lines(no_evidence) == ["blind"]
    assert status_lines(None) == [] and status_lines("text") == []
    assert single_row("drift", passed) == [("drift", passed)]
    assert single_row("drift", {"message": "no status"}) == [] and single_row("drift", None) == []
    per_camera = {"a": failed, "b": passed, "c": "not an entry"}
    assert camera_rows("calibration", per_camera) == [
        ("calibration (camera a)", failed), ("calibration (camera b)", passed)]
    assert camera_lines(per_camera) == ["registration off by 3 px"]
    assert camera_rows("calibration", None) == [] and camera_lines(None) == []
