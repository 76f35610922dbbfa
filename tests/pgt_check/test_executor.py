"""Executors (serial / process / Dask), crash retries, SIGINT, SIGKILL + resume, bounded memory.

The tests use ``FakeChecker``: a picklable stand-in for ``runner.FrameChecker`` with the same
``measure(frame) -> record`` interface that does a little numpy work and can be told to crash
(``os._exit``), hang or raise for given frame ids. Child processes import this module by name
(spawn passes ``sys.path``), and ``python test_executor.py --cli ...`` runs the real CLI on fake
frames (``runner.load_trajectory`` and ``runner.build_frame_checker`` replaced).

frames.csv of two runs is compared **without its timing columns** (``t_*_s``, ``time_s``):
they are wall-clock measurements and differ between any two runs.
"""

from __future__ import annotations

import csv
import functools
import io
import json
import os
import pickle
import signal
import subprocess
import sys
import time
import zlib
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from pgt_check.config import RunConfig
from pgt_check.enhance.base import Evidence
from pgt_check.executor import CheckerSetupError, ExecutorStats, iter_results
from pgt_check.measure import FrameMeasurement
from pgt_check.report.outputs import STAGES
from pgt_check.types import Camera, Frame, Trajectory

HERE = Path(__file__).resolve().parent
REPO = HERE.parents[1]
TIMING = set(STAGES)  # every timing column of frames.csv
CAMERA = Camera.pinhole(64, 48, 50.0, 50.0, 31.5, 23.5)


def make_frames(n: int, start: int = 0):
    """A generator of ``n`` frames along a line (no list: memory tests stream them)."""
    for i in range(start, start + n):
        pose = np.eye(4)
        pose[:3, 3] = (0.01 * i, 0.0, 1.0)
        yield Frame(f"f{i:06d}", CAMERA, pose, image_path=f"rgb/{i:06d}.png", timestamp=float(i))


@dataclass
class FakeChecker:
    """Picklable stand-in for FrameChecker: deterministic records from the frame id and pose."""

    work: int = 32
    delay_s: float = 0.0
    crash_ids: tuple[str, ...] = ()
    crash_once_ids: tuple[str, ...] = ()
    hang_ids: tuple[str, ...] = ()
    raise_ids: tuple[str, ...] = ()
    marker_dir: str | None = None
    fail_setup: bool = False

    def __post_init__(self) -> None:
        if self.fail_setup:
            raise RuntimeError("no GL context available (fake)")
        self.n_built = 1
        self.closed = False

    def measure(self, frame: Frame, keep: Any = None) -> FrameMeasurement:
        from pgt_check.measure import MeasureReason, PathMeasurement, Timings, failed_measurement

        fid = frame.frame_id
        if fid in self.crash_ids:
            os._exit(3)
        if fid in self.crash_once_ids:
            marker = Path(self.marker_dir or ".") / f"crashed-{fid}"
            if not marker.exists():
                marker.touch()
                os._exit(3)
        if fid in self.hang_ids:
            time.sleep(3600)
        if fid in self.raise_ids:
            raise ValueError(f"fake failure on {fid}")
        t = time.perf_counter()
        if self.delay_s:
            time.sleep(self.delay_s)
        rng = np.random.default_rng(zlib.crc32(fid.encode()))
        img = rng.random((self.work, self.work, 3), dtype=np.float32)
        score = float(np.abs(np.fft.rfft2(img[..., 0])).mean())
        path = PathMeasurement(
            kind="raw", method="render", evidence=Evidence.ABSOLUTE, n_kpts_render=100,
            n_kpts_photo=100, n_matches=80, n_inliers=60, inlier_ratio=0.75, reason="",
            photo_from_render=((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0)),
            corner_error_px=round((zlib.crc32(fid.encode()) % 40) / 10.0, 3),
            shift_dx_px=round(float(frame.world_from_cam[0, 3]), 6), shift_dy_px=0.0,
            zoom=round(score, 6),
        )
        m = failed_measurement(frame, MeasureReason.NONE)
        # the worker's pid travels in error_detail (not in frames.csv) so tests count workers
        return replace(
            m, coverage=0.9, shading="vertex", error_detail=f"pid={os.getpid()}", raw=path,
            verdict_path="raw",
            timings=Timings(total=time.perf_counter() - t),
        )

    def close(self) -> None:
        self.closed = True


def by_id(records) -> dict[str, dict]:
    rows = [r.row() if isinstance(r, FrameMeasurement) else r for r in records]
    return {
        r["frame_id"]: {
            k: v for k, v in r.items()
            if k not in TIMING and not (k == "error_detail" and v.startswith("pid="))
        }
        for r in rows
    }


def run_records(config: RunConfig, n: int, **fake) -> tuple[list[dict], ExecutorStats]:
    stats = ExecutorStats()
    factory = functools.partial(FakeChecker, **fake)
    return list(iter_results(make_frames(n), factory, config, stats=stats)), stats


def csv_without_timing(path: Path) -> list[dict[str, str]]:
    rows = list(csv.DictReader(io.StringIO(path.read_text())))
    return [{k: v for k, v in row.items() if k not in TIMING} for row in rows]


# -- in-process CLI on fake frames (used by the subprocess tests) ------------------------------
def fake_load_trajectory(config: RunConfig) -> Trajectory:
    return Trajectory(
        tuple(make_frames(int(os.environ.get("PGT_FAKE_FRAMES", "40")))),
        source="fake",
        format="fake",
    )


def fake_build_checker(config: RunConfig, references=None, panel_sink=None) -> FakeChecker:
    return FakeChecker(**json.loads(os.environ.get("PGT_FAKE_CHECKER", "{}")))


def cli_main(argv: list[str], monkeypatch: pytest.MonkeyPatch | None = None) -> int:
    """The real CLI on fake frames (patches runner's reader and checker factory)."""
    from pgt_check import cli, runner

    setattr_ = monkeypatch.setattr if monkeypatch is not None else setattr
    setattr_(runner, "load_trajectory", fake_load_trajectory)
    setattr_(runner, "build_frame_checker", fake_build_checker)
    setattr_(runner, "preflight", fake_build_checker)  # no mesh to validate on fake frames
    return cli.main(argv)


def cli_argv(out: Path, *extra: str) -> list[str]:
    return ["fake-trajectory.txt", "--mesh", "fake.ply", "--out", str(out), "-q", *extra]


def start_cli(out: Path, *extra: str, frames: int, checker: dict) -> subprocess.Popen:
    env = dict(
        os.environ,
        PGT_FAKE_FRAMES=str(frames),
        PGT_FAKE_CHECKER=json.dumps(checker),
        PYTHONPATH=os.pathsep.join([str(REPO), str(HERE)]),
    )
    return subprocess.Popen(
        [sys.executable, str(Path(__file__)), "--cli", *cli_argv(out, *extra)],
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )


def n_lines(path: Path) -> int:
    return path.read_bytes().count(b"\n") if path.is_file() else 0


def wait_for_lines(path: Path, n: int, proc: subprocess.Popen, timeout: float = 60) -> None:
    t_end = time.monotonic() + timeout
    while n_lines(path) < n:
        assert proc.poll() is None, proc.communicate()
        assert time.monotonic() < t_end, "child made no progress"
        time.sleep(0.05)


# -- tests -------------------------------------------------------------------------------------
def test_frames_pickle():
    frame = next(make_frames(1, start=7))
    back = pickle.loads(pickle.dumps(frame))
    assert back.frame_id == frame.frame_id and back.camera == frame.camera
    np.testing.assert_array_equal(back.world_from_cam, frame.world_from_cam)


def test_serial_builds_once_and_closes():
    built = []

    def factory():
        c = FakeChecker()
        built.append(c)
        return c

    recs = list(iter_results(make_frames(5), factory, RunConfig()))
    assert len(recs) == 5 and len(built) == 1 and built[0].closed


def test_process_matches_serial():
    serial, _ = run_records(RunConfig(), 30)
    # 0.1 s a frame: on a loaded machine the second worker starts later than 30 x 0.01 s
    # (the first one then took every frame and the "both workers" check below failed)
    proc, stats = run_records(RunConfig(executor="process", workers=2), 30, delay_s=0.1)
    assert by_id(proc) == by_id(serial)
    assert len(proc) == 30 and stats.worker_crashes == 0
    assert len({r.error_detail for r in proc}) == 2  # both workers were used, each built once


def test_process_crash_is_retried_then_recorded(tmp_path):
    cfg = RunConfig(executor="process", workers=2)
    recs, stats = run_records(
        cfg, 12, crash_once_ids=("f000003",), crash_ids=("f000007",), marker_dir=str(tmp_path)
    )
    got = by_id(recs)
    assert set(got) == {f"f{i:06d}" for i in range(12)}
    assert got["f000003"]["error"] == ""  # crashed once, fine on the retry
    assert got["f000007"]["error"] == "worker_crashed"
    assert "2 times" in got["f000007"]["error_detail"]
    assert "exit code 3" in got["f000007"]["error_detail"]
    assert stats.crashed_frames == ["f000007"]
    serial, _ = run_records(RunConfig(), 12)
    good = by_id(serial)
    assert all(got[k] == good[k] for k in got if k != "f000007")


def test_measure_exception_is_an_internal_error_record():
    for cfg in (RunConfig(), RunConfig(executor="process", workers=1)):
        recs, _ = run_records(cfg, 4, raise_ids=("f000002",))
        got = by_id(recs)
        assert got["f000002"]["error"] == "internal_error"
        assert "fake failure" in got["f000002"]["error_detail"]
        with pytest.raises(ValueError, match="fake failure"):
            run_records(
                RunConfig(executor=cfg.executor, workers=1, fail_fast=True),
                4,
                raise_ids=("f000002",),
            )


@pytest.mark.parametrize("executor", ["serial", "process"])
def test_setup_failure_ends_the_run(executor):
    with pytest.raises(CheckerSetupError, match="no GL context"):
        run_records(RunConfig(executor=executor, workers=1), 3, fail_setup=True)


def test_check_frames_store_and_rerun(tmp_path, monkeypatch):
    from pgt_check.errors import InputError

    out = tmp_path / "run"
    assert cli_main(cli_argv(out), monkeypatch) in (0, 1)
    first = csv_without_timing(out / "frames.csv")
    summary = json.loads((out / "summary.json").read_text())
    assert summary["executor"]["frames_measured"] == 40 and len(first) == 40
    # same settings: nothing is measured again, same frames.csv
    assert cli_main(cli_argv(out, "--executor", "process", "--workers", "2"), monkeypatch) in (0, 1)
    summary = json.loads((out / "summary.json").read_text())
    assert summary["executor"]["frames_reused"] == 40
    assert summary["executor"]["frames_measured"] == 0
    assert csv_without_timing(out / "frames.csv") == first
    # changed measurement settings: exit 2 unless --resume / --overwrite
    assert cli_main(cli_argv(out, "--max-keypoints", "100"), monkeypatch) == 2
    from pgt_check.runner import PreparedRun, check_frames

    with pytest.raises(InputError, match="match.max_keypoints"):
        cfg = RunConfig.from_dict({"out": str(out), "match": {"max_keypoints": 7}})
        check_frames(PreparedRun.of(list(make_frames(3)), cfg, input_keys={}, inputs={}),
                     cfg, FakeChecker)
    assert cli_main(cli_argv(out, "--max-keypoints", "100", "--resume"), monkeypatch) in (0, 1)
    summary = json.loads((out / "summary.json").read_text())
    assert summary["executor"]["frames_measured"] == 40
    # a verdict-only setting never re-measures
    assert cli_main(
        cli_argv(out, "--max-keypoints", "100", "--min-inliers", "30"), monkeypatch
    ) in (0, 1)
    assert json.loads((out / "summary.json").read_text())["executor"]["frames_measured"] == 0
    # the threshold drives --enhance auto (the default): it is a measurement setting there
    with pytest.raises(InputError, match="verdict.threshold_px"):
        cfg = RunConfig.from_dict({"out": str(out), "match": {"max_keypoints": 100},
                                   "verdict": {"threshold_px": 2.0}})
        check_frames(PreparedRun.of(list(make_frames(3)), cfg, input_keys={}, inputs={}),
                     cfg, FakeChecker)


def test_sigint_stops_cleanly_and_resume_completes(tmp_path, monkeypatch):
    out = tmp_path / "run"
    proc = start_cli(
        out, "--executor", "process", "--workers", "2", frames=60, checker={"delay_s": 0.1}
    )
    wait_for_lines(out / "records.jsonl", 6, proc)
    proc.send_signal(signal.SIGINT)
    stdout, stderr = proc.communicate(timeout=60)
    assert proc.returncode == 130, stderr
    assert "interrupted: " in stderr and "/60 frames done; resume with: pgt-check" in stderr
    assert "--resume" in stderr
    done = int(stderr.split("interrupted: ")[1].split("/")[0])
    assert 6 <= done < 60 and n_lines(out / "records.jsonl") == done
    assert not (out / "frames.csv").exists()
    monkeypatch.setenv("PGT_FAKE_FRAMES", "60")
    assert cli_main(cli_argv(out, "--resume"), monkeypatch) in (0, 1)
    summary = json.loads((out / "summary.json").read_text())
    assert summary["executor"]["frames_reused"] == done
    assert summary["executor"]["frames_measured"] == 60 - done


def test_sigkill_and_resume_give_the_same_frames_csv(tmp_path, monkeypatch):
    import psutil

    ref = tmp_path / "ref"
    assert cli_main(cli_argv(ref), monkeypatch) in (0, 1)
    out = tmp_path / "killed"
    proc = start_cli(
        out, "--executor", "process", "--workers", "2", frames=40, checker={"delay_s": 0.1}
    )
    wait_for_lines(out / "records.jsonl", 8, proc)
    workers = psutil.Process(proc.pid).children(recursive=True)
    proc.kill()  # SIGKILL the run only, as `kill -9 PID` would
    proc.communicate(timeout=30)
    # the orphaned pool workers notice and exit by themselves
    _, alive = psutil.wait_procs(workers, timeout=15)
    for p in alive:
        p.kill()
    assert not alive, f"orphaned workers still running: {alive}"
    with open(out / "records.jsonl", "ab") as f:  # as if killed in the middle of a write
        f.write(b'{"_fingerprint": "abc", "frame_id": "f0000')
    done_before = n_lines(out / "records.jsonl")
    assert 8 <= done_before < 40
    assert cli_main(
        cli_argv(out, "--resume", "--executor", "process", "--workers", "2"), monkeypatch
    ) in (0, 1)
    assert csv_without_timing(out / "frames.csv") == csv_without_timing(ref / "frames.csv")
    summary = json.loads((out / "summary.json").read_text())
    assert summary["executor"]["frames_reused"] == done_before
    # records.jsonl is append-only (completion order, never rewritten) and holds every frame
    # exactly once; run.json keeps the trajectory order for `pgt-check report`
    ids = [
        json.loads(line)["frame_id"] for line in (out / "records.jsonl").read_text().splitlines()
    ]
    assert sorted(ids) == [f"f{i:06d}" for i in range(40)]
    run_info = json.loads((out / "run.json").read_text())
    assert run_info["frame_ids"] == [f"f{i:06d}" for i in range(40)]


MEMORY_CHILD = """
import functools, json, resource, sys
from pgt_check.config import RunConfig
from pgt_check.executor import iter_results
from pgt_check.store import RecordStore
import test_executor as t

n, out = int(sys.argv[1]), sys.argv[2]
cfg = RunConfig(executor="process", workers=2)
with RecordStore.open(out, "fp") as store:
    for rec in iter_results(t.make_frames(n), functools.partial(t.FakeChecker, work=128), cfg):
        store.append(rec.to_json())
    assert len(store.done_ids()) == n
print(json.dumps({"self_kb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss,
                  "children_kb": resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss}))
"""


@pytest.mark.slow
def test_memory_is_bounded_in_the_frame_count(tmp_path):
    """Peak RSS of the run process and its workers: 5000 frames vs 1000 (each frame makes a
    128x128x3 float32 image, 200 KB; keeping renders or records would add > 20 MB)."""
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(REPO), str(HERE)]))
    peaks = {}
    for n in (1000, 5000):
        res = subprocess.run(
            [sys.executable, "-c", MEMORY_CHILD, str(n), str(tmp_path / str(n))],
            env=env,
            capture_output=True,
            text=True,
            timeout=300,
        )
        assert res.returncode == 0, res.stderr
        peaks[n] = json.loads(res.stdout.strip().splitlines()[-1])
    grow_self = (peaks[5000]["self_kb"] - peaks[1000]["self_kb"]) / 1024
    grow_children = (peaks[5000]["children_kb"] - peaks[1000]["children_kb"]) / 1024
    print(
        f"peak RSS MiB: {peaks}; growth 1000 -> 5000 frames: run {grow_self:.1f}, "
        f"workers {grow_children:.1f}"
    )
    assert grow_self < 8, peaks
    assert grow_children < 8, peaks


# -- Dask ----------------------------------------------------------------------------------------
@pytest.mark.dask
def test_dask_local_cluster_matches_serial():
    pytest.importorskip("distributed")
    serial, _ = run_records(RunConfig(), 20)
    dask_recs, stats = run_records(RunConfig(executor="dask", workers=2), 20, delay_s=0.01)
    assert by_id(dask_recs) == by_id(serial)
    assert stats.workers == 2


def test_dask_lost_result_is_measured_again_not_an_error():
    """A frame whose result was lost with a worker after it finished (future status "lost")
    goes back to the queue; it is not recorded as an internal error (seen in CI: a crash next
    to a finished frame recorded that frame as ``internal error: None``)."""
    import threading

    from pgt_check.executor.common import Task
    from pgt_check.executor.dask import _DaskRun

    class Lost:
        status = "lost"

        def exception(self):
            return None

    frame = next(make_frames(1))
    run = _DaskRun(
        None, FakeChecker, RunConfig(executor="dask"), threading.Event(), ExecutorStats(),
        as_completed=lambda: None, killed=RuntimeError,
    )
    task = Task(frame)
    assert run.outcome(Lost(), task) is None
    assert list(run.retry) == [task] and task.crashes == 0 and not task.isolated


@pytest.mark.dask
def test_dask_scheduler_address_and_crash(tmp_path):
    distributed = pytest.importorskip("distributed")
    import dask

    settings = {"distributed.scheduler.allowed-failures": 0}
    with (
        dask.config.set(settings),
        distributed.LocalCluster(
            n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None
        ) as cluster,
    ):
        cfg = RunConfig(executor="dask", scheduler=cluster.scheduler_address)
        recs, stats = run_records(
            cfg, 10, crash_once_ids=("f000004",), crash_ids=("f000006",), marker_dir=str(tmp_path)
        )
    got = by_id(recs)
    assert len(got) == 10
    assert got["f000004"]["error"] == ""
    assert got["f000006"]["error"] == "worker_crashed"
    serial, _ = run_records(RunConfig(), 10)
    good = by_id(serial)
    assert all(got[k] == good[k] for k in got if k != "f000006")


# -- real data (enabled once pgt_check.io and pgt_check.render are merged) -------------------------
@pytest.mark.dask
@pytest.mark.slow
def test_sample_data_process_and_dask_match_serial(tmp_path, sample_scene):
    """The real checker (renderer + SIFT + homography) gives the same frames.csv (timing
    columns aside) under the serial, process and Dask executors."""
    from pgt_check.runner import run

    base = {
        "input": {
            "trajectory": str(sample_scene / "trajectories.txt"),
            "mesh": str(sample_scene / "mesh.glb"),
        },
        "limit": 10,
        "report_details": 0,
        # corrections unbounded in time: a budget relative to the main pass's time cuts them
        # differently when the machine is loaded differently (not an executor difference)
        "correct": {"budget": 0},
    }
    tables = {}
    for name, extra in {
        "serial": {},
        "process": {"executor": "process", "workers": 2},
        "dask": {"executor": "dask", "workers": 2},
    }.items():
        cfg = RunConfig.from_dict({**base, **extra, "out": str(tmp_path / name)})
        run(cfg)
        tables[name] = csv_without_timing(tmp_path / name / "frames.csv")
    assert len(tables["serial"]) == 10  # one row per frame
    assert tables["process"] == tables["serial"]
    assert tables["dask"] == tables["serial"]


class _Counted:
    built = 0

    def __init__(self) -> None:
        type(self).built += 1
        self.closed = 0
        self.seen: list[Any] = []

    def measure(self, frame: Any, keep: Any = None) -> Any:
        self.seen.append((frame, keep))
        return frame

    def close(self) -> None:
        self.closed += 1


def test_checker_lender_borrows_lends_and_hands_over_one_checker():
    from pgt_check.executor import CheckerLender

    _Counted.built = 0
    lender = CheckerLender(_Counted)
    a = lender.borrow()
    assert lender.borrow() is a and _Counted.built == 1  # built once, on first need
    lent = lender.lend()
    assert lent.measure("f", "k") == "f" and a.seen == [("f", "k")]
    lent.close()  # an executor closing what it got: left to the owner
    assert a.closed == 0
    lender.close()
    lender.close()
    assert a.closed == 1
    # hand_over: the built checker once (the taker owns it), then new ones
    built = _Counted()
    lender = CheckerLender(_Counted, built)
    assert lender.hand_over() is built
    other = lender.hand_over()
    assert other is not built and isinstance(other, _Counted)
    lender.close()
    assert built.closed == 0 and other.closed == 0  # nothing left here to close
    # a built checker no pass took is closed by its owner
    unused = _Counted()
    CheckerLender(_Counted, unused).close()
    assert unused.closed == 1


if __name__ == "__main__" and sys.argv[1:2] == ["--cli"]:
    import test_executor  # pickle this module's functions by its importable name

    sys.exit(test_executor.cli_main(sys.argv[2:]))
