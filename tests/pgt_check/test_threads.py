"""OpenCV's and BLAS's thread counts: set per run, restored for the API's caller, configurable,
same results."""

from __future__ import annotations

import logging

import cv2
import pytest

from pgt_check.config import RunConfig
from pgt_check.errors import ConfigError
from pgt_check.io import read_trajectory
from pgt_check.threads import ThreadLimits, limit_threads, run_threads


def _blas_threads() -> set[int]:
    from threadpoolctl import threadpool_info

    return {i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"}


@pytest.fixture
def caller_threads():
    """The caller's own settings (OpenCV 3 threads, BLAS 2), restored after the test."""
    from threadpoolctl import threadpool_limits

    before = cv2.getNumThreads()
    cv2.setNumThreads(3)
    with threadpool_limits(limits=2, user_api="blas"):
        yield 3
    cv2.setNumThreads(before)


def test_block_sets_and_restores_even_on_error(caller_threads):
    with run_threads(1):
        assert cv2.getNumThreads() == 1 and _blas_threads() == {1}
        limit_threads(5)  # inside a block: the block's count, undone with it
        assert cv2.getNumThreads() == 1 and _blas_threads() == {1}
    assert cv2.getNumThreads() == caller_threads and _blas_threads() == {2}
    with pytest.raises(RuntimeError), run_threads(2):
        assert cv2.getNumThreads() == 2
        raise RuntimeError("boom")
    assert cv2.getNumThreads() == caller_threads and _blas_threads() == {2}
    with run_threads(None):  # the libraries' defaults: left alone
        assert cv2.getNumThreads() == caller_threads and _blas_threads() == {2}
    with pytest.raises(ValueError, match=">= 1"):
        ThreadLimits(0)


def test_outside_a_block_the_limit_stays(caller_threads):
    limits = ThreadLimits(1)
    limit_threads(1)  # what a worker process does
    assert cv2.getNumThreads() == 1 and _blas_threads() == {1}
    limits.restore()  # nothing applied through this one: a no-op
    assert cv2.getNumThreads() == 1


def test_config_default_zero_and_range():
    assert RunConfig().threads == 1
    assert RunConfig.from_dict({"threads": 0}).threads is None  # OpenCV's default
    assert RunConfig.from_dict({"threads": 4}).threads == 4
    with pytest.raises((ConfigError, ValueError), match="threads"):
        RunConfig.from_dict({"threads": -2})
    # not a measurement setting: stored measurements stay valid whatever the thread count
    assert (RunConfig.from_dict({"threads": 4}).measurement_fingerprint()
            == RunConfig().measurement_fingerprint())


def test_cli_option_reaches_the_config():
    from pgt_check.commands.check import build_parser, load_config

    args = build_parser().parse_args(["t.txt", "--mesh", "m.ply", "--threads", "0"])
    assert load_config(args).threads is None


def test_a_run_measures_with_its_threads_and_gives_the_callers_back(
        tmp_path, sample_scene, caller_threads, monkeypatch):
    from pgt_check.api import check
    from pgt_check.measure import checker as checker_mod

    seen = []
    measure = checker_mod.FrameChecker.measure

    def spy(self, frame, *a, **kw):
        seen.append((cv2.getNumThreads(), frozenset(_blas_threads())))
        return measure(self, frame, *a, **kw)

    monkeypatch.setattr(checker_mod.FrameChecker, "measure", spy)
    traj = read_trajectory(sample_scene / "trajectories.txt")
    out = {}
    for threads in (1, 2):
        df = check(traj, sample_scene / "mesh.glb", out=str(tmp_path / f"t{threads}"),
                   limit=3, report_details=0, threads=threads, correct={"frames": "none"})
        out[threads] = df
        assert seen and set(seen) == {(threads, frozenset({threads}))}
        seen.clear()
        assert cv2.getNumThreads() == caller_threads and _blas_threads() == {2}
    cols = ["frame_id", "verdict", "corner_error_px", "n_inliers"]
    assert out[1][cols].equals(out[2][cols])


def test_without_threadpoolctl_only_opencv_is_limited(caller_threads, monkeypatch, caplog):
    import sys

    monkeypatch.setitem(sys.modules, "threadpoolctl", None)  # import fails
    # the warning is captured whatever an earlier test in this process left on the logger
    # (a command's log level, a library's logging.config that disables existing loggers)
    log = logging.getLogger("pgt_check.threads")
    monkeypatch.setattr(log, "disabled", False)
    caplog.set_level(logging.WARNING, logger="pgt_check.threads")
    with run_threads(1):
        assert cv2.getNumThreads() == 1
    assert cv2.getNumThreads() == caller_threads
    assert "threadpoolctl is not installed" in caplog.text
