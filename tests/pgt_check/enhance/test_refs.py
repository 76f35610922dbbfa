"""``enhance.refs``: references chosen among the frames whose own absolute evidence passed
(``absolute_passes``, ``verified_references``; issue 38), on judged runs built by hand. The
render lookup of ``pgt-check enhance`` is tested with the subcommand
(``tests/pgt_check/test_enhance_cli.py``)."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from types import SimpleNamespace

import numpy as np

from pgt_check.config import RunConfig
from pgt_check.enhance.refs import absolute_passes, verified_references
from pgt_check.geometry.transforms import make_rigid
from pgt_check.types import Camera, Frame, Trajectory
from pgt_check.verdict.judgement import Verdict

CAM = Camera.pinhole(64, 48, 50, 50, 31.5, 23.5)


def _traj(n: int) -> Trajectory:
    return Trajectory(tuple(
        Frame(str(i), CAM, make_rigid(np.eye(3), [0.1 * i, 0, 0]), f"{i}.jpg", Path(f"{i}.jpg"))
        for i in range(n)
    ), "synthetic", "lamar")


def _frame(fid, verdict, evidence, raw, refs=(), enhance_ran=True, own=None):
    """``own``: what the frame's own absolute evidence says (default: its raw path's verdict)."""
    paths = [SimpleNamespace(reference_id=r) for r in refs]
    m = SimpleNamespace(frame_id=fid, enhance_ran=enhance_ran,
                        enhanced=paths[0] if paths else None,
                        enhanced_alternatives=tuple(paths[1:]))
    j = SimpleNamespace(verdict=Verdict(verdict), evidence=evidence, raw_verdict=raw,
                        own_verdict=raw if own is None else own)
    return SimpleNamespace(frame_id=fid, measurement=m, judgement=j)


def _result(frames, left_out=()):
    return SimpleNamespace(frames=frames, shared=SimpleNamespace(left_out=frozenset(left_out)))


def test_absolute_passes_are_own_absolute_evidence_and_not_left_out():
    res = _result([
        _frame("0", "PASS", "absolute", "PASS"),
        _frame("1", "FAIL", "relative", "PASS"),  # the raw path alone passed
        _frame("2", "PASS", "relative", "FAIL"),  # a reference decided: not its own evidence
        _frame("3", "PASS", "absolute", ""),  # e.g. the edge path decided
        _frame("4", "PASS", "absolute", "PASS"),  # left out by the run-level checks
        _frame("5", "UNVERIFIABLE", "none", "UNVERIFIABLE"),
        # FAIL on a failed registration check, its own edges passed: right up to the shared
        # error, which a relative path cancels (frame and reference carry it alike)
        _frame("6", "FAIL", "absolute", "UNVERIFIABLE", own="PASS"),
        _frame("7", "FAIL", "absolute", "UNVERIFIABLE", own="FAIL"),  # off on its own
    ], left_out={"4"})
    assert absolute_passes(res) == {"0", "1", "3", "6"}


def test_frames_leaning_on_unverified_references_get_verified_ones():
    """Frames 4 and 5 are wrong (their raw path failed); frame 3 failed on a reference to 4,
    frame 6 was starved by 5 (UNVERIFIABLE): both get references among the frames that passed.
    A frame that passed on its own evidence, one whose references passed, and one whose
    enhanced path did not run keep theirs."""
    traj = _traj(10)
    res = _result([
        _frame("0", "PASS", "absolute", "PASS", ("1",)),
        _frame("1", "PASS", "absolute", "PASS", ("0",)),
        _frame("2", "PASS", "absolute", "PASS", ("3", "1")),  # passed on its own: kept
        _frame("3", "FAIL", "relative", "UNVERIFIABLE", ("4", "2")),
        _frame("4", "FAIL", "relative", "FAIL", ("3", "5")),
        _frame("5", "FAIL", "absolute", "FAIL", (), enhance_ran=False),
        _frame("6", "UNVERIFIABLE", "none", "UNVERIFIABLE", ("5", "7")),
        _frame("7", "PASS", "relative+registration", "UNVERIFIABLE", ("8", "6")),
        _frame("8", "PASS", "absolute", "PASS", ("7",)),
        _frame("9", "PASS", "absolute", "PASS", ("8",)),
    ])
    new = verified_references(traj, res, RunConfig())
    ok = absolute_passes(res)
    assert ok == {"0", "1", "2", "8", "9"}
    # 3, 4, 6 leaned on frames outside ok; 7 on 6 (relative evidence, 8 is fine but 6 not)
    assert set(new) == {"3", "4", "6", "7"}
    for fid, refs in new.items():
        assert refs and {f.frame_id for f in refs} <= ok, (fid, refs)
    assert [f.frame_id for f in new["3"]] == ["2", "1"]  # the nearest that passed
    assert [f.frame_id for f in new["6"]] == ["8", "9"]


def test_nothing_is_measured_again_without_the_enhanced_path_or_when_all_passed():
    traj = _traj(4)
    res = _result([_frame(str(i), "FAIL", "relative", "FAIL", (str((i + 1) % 4),))
                   for i in range(4)])
    cfg = RunConfig()
    off = replace(cfg, enhance=replace(cfg.enhance, mode="never"))
    assert verified_references(traj, res, off) == {}
    # no frame passed: no reference can serve, every frame is left without one
    new = verified_references(traj, res, RunConfig())
    assert set(new) == {"0", "1", "2", "3"} and all(r == () for r in new.values())
    ok = _result([_frame(str(i), "PASS", "absolute", "PASS", (str((i + 1) % 4),))
                  for i in range(4)])
    assert verified_references(traj, ok, RunConfig()) == {}
