"""Throughput of the executors: frames/s for serial, process x1/x2, Dask LocalCluster x2.

Real data (needs pgt_check.io and pgt_check.render)::

    PGT_SHARED_DATA=../shared/data python benchmarks/scaling.py --out reports/scaling.json

Synthetic frames and a CPU-bound stand-in checker (measures the executor layer alone)::

    python benchmarks/scaling.py --synthetic --frames 200 --work-ms 40

Against an existing Dask cluster (workers must see the same data paths)::

    python benchmarks/scaling.py --modes dask --scheduler tcp://HOST:8786

Per mode it times one pass over the frames with ``executor.iter_results`` and reports
``startup_s`` (until the first record: pool or cluster start, checker build), steady frames/s
(``(n - 1) / (t_last - t_first)``) and end-to-end frames/s (``n / total``); efficiency is the
steady rate divided by workers x the rate of one process worker. Writes JSON with metadata.
Not a test: nothing here asserts a time.
"""

from __future__ import annotations

import argparse
import functools
import json
import os
import platform
import subprocess
import sys
import time
import zlib
from dataclasses import dataclass
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]

MODES = {
    "serial": ("serial", 1),
    "process1": ("process", 1),
    "process2": ("process", 2),
    "dask2": ("dask", 2),
}


@dataclass
class SyntheticChecker:
    """CPU-bound stand-in for FrameChecker: a fixed amount of single-threaded numpy per frame
    (``iterations`` FFTs, calibrated to ``--work-ms`` on an idle core), so contention shows."""

    iterations: int = 100
    size: int = 96

    def measure(self, frame, keep=None) -> dict:
        import numpy as np

        rng = np.random.default_rng(zlib.crc32(frame.frame_id.encode()))
        img = rng.random((self.size, self.size), dtype=np.float32)
        acc = 0.0
        for _ in range(self.iterations):
            acc += float(np.abs(np.fft.rfft2(img)).mean())
        return {"frame_id": frame.frame_id, "error": "", "score": acc}


def calibrate(work_ms: float) -> int:
    """FFT iterations that take ``work_ms`` here (best of 5, i.e. the least disturbed)."""
    probe = SyntheticChecker(iterations=200)
    frame = next(synthetic_frames(1))
    best = min(_timed(probe, frame) for _ in range(5))
    return max(1, round(200 * work_ms / 1000 / best))


def _timed(checker, frame) -> float:
    t = time.perf_counter()
    checker.measure(frame)
    return time.perf_counter() - t


def synthetic_frames(n: int):
    import numpy as np

    from pgt_check.types import Camera, Frame

    cam = Camera.pinhole(640, 480, 525.0, 525.0, 319.5, 239.5)
    for i in range(n):
        pose = np.eye(4)
        pose[:3, 3] = (0.01 * i, 0.0, 0.0)
        yield Frame(f"{i:06d}", cam, pose, image_path=f"{i:06d}.png")


def real_config_dict(data: Path) -> dict:
    return {
        "input": {
            "trajectory": str(data / "trajectories.txt"),
            "format": "lamar",
            "images": str(data / "images.txt"),
            "sensors": str(data / "sensors.txt"),
            "mesh": str(data / "mesh.ply"),
        }
    }


def time_mode(frames, factory, config) -> dict:
    from pgt_check.executor import ExecutorStats, iter_results

    stats = ExecutorStats()
    t0 = time.perf_counter()
    stamps = []
    errors = 0
    for rec in iter_results(iter(frames), factory, config, stats=stats):
        stamps.append(time.perf_counter())
        # a FrameMeasurement (real checker) or a dict (the synthetic stand-in)
        errors += bool(rec.get("error") if isinstance(rec, dict) else rec.error.value)
    t_end = time.perf_counter()
    n = len(stamps)
    steady = (n - 1) / (stamps[-1] - stamps[0]) if n > 1 and stamps[-1] > stamps[0] else None
    return {
        "frames": n,
        "errors": errors,
        "workers": stats.workers,
        "total_s": t_end - t0,
        "startup_s": stamps[0] - t0 if stamps else None,
        "fps_steady": steady,
        "fps_end_to_end": n / (t_end - t0),
    }


def metadata() -> dict:
    import numpy

    try:
        commit = subprocess.run(
            ["git", "-C", str(REPO), "rev-parse", "HEAD"], capture_output=True, text=True
        ).stdout.strip()
    except OSError:
        commit = ""
    out = {
        "commit": commit,
        "python": platform.python_version(),
        "numpy": numpy.__version__,
        "cpus": len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else None,
        "machine": platform.machine(),
        "LP_NUM_THREADS": os.environ.get("LP_NUM_THREADS"),
        "OMP_NUM_THREADS": os.environ.get("OMP_NUM_THREADS"),
    }
    try:
        import distributed

        out["distributed"] = distributed.__version__
    except ImportError:
        pass
    return out


def _frames_and_factory(args: argparse.Namespace) -> tuple[list, functools.partial, dict]:
    """(frames, checker factory, base config dict): synthetic stand-ins or the real data."""
    from pgt_check.config import RunConfig

    if args.synthetic:
        frames = list(synthetic_frames(args.frames or 200))
        factory = functools.partial(SyntheticChecker, iterations=calibrate(args.work_ms))
        base: dict = {}
    else:
        from pgt_check import runner

        base = real_config_dict(args.data)
        frames = list(runner.load_trajectory(RunConfig.from_dict(base)).frames)
        if args.frames:
            frames = frames[: args.frames]
        factory = functools.partial(runner.build_frame_checker, RunConfig.from_dict(base))
    return frames, factory, base


def _add_efficiency(results: dict) -> None:
    """Each mode's steady rate over workers x the rate of one process worker (if measured)."""
    one = results.get("process1", {}).get("median", {}).get("fps_steady")
    if one:
        for r in results.values():
            m = r["median"]
            m["efficiency"] = (m["fps_steady"] or 0) / (m["workers"] * one)


def _print_table(results: dict) -> None:
    """Print the Markdown table of the modes' medians."""
    print("| mode | workers | startup s | steady frames/s | end-to-end frames/s | efficiency |")
    print("|---|---|---|---|---|---|")
    for mode, r in results.items():
        m = r["median"]
        eff = f"{m['efficiency']:.2f}" if "efficiency" in m else "-"
        print(
            f"| {mode} | {m['workers']} | {m['startup_s']:.2f} | {m['fps_steady'] or 0:.2f} "
            f"| {m['fps_end_to_end']:.2f} | {eff} |"
        )


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    default_data = Path(os.environ.get("PGT_SHARED_DATA", REPO.parent / "shared" / "data"))
    p.add_argument("--data", type=Path, default=default_data / "7scenes_redkitchen")
    p.add_argument("--modes", default="serial,process1,process2,dask2")
    p.add_argument("--frames", type=int, default=None, help="first N frames (default: all)")
    p.add_argument("--repeats", type=int, default=1)
    p.add_argument("--scheduler", default=None, help="Dask scheduler address for 'dask' modes")
    p.add_argument("--synthetic", action="store_true", help="stand-in checker, no real data")
    p.add_argument("--work-ms", type=float, default=40.0)
    p.add_argument("--out", type=Path, default=None, help="JSON result file")
    args = p.parse_args(argv)

    from pgt_check.config import RunConfig

    frames, factory, base = _frames_and_factory(args)

    results = {}
    for mode in args.modes.split(","):
        if mode == "dask" or mode.startswith("dask") and args.scheduler:
            executor, workers = "dask", None
        else:
            executor, workers = MODES[mode]
        cfg = RunConfig.from_dict(
            {**base, "executor": executor, "workers": workers, "scheduler": args.scheduler}
            if executor == "dask"
            else {**base, "executor": executor, "workers": workers}
        )
        runs = [time_mode(frames, factory, cfg) for _ in range(args.repeats)]
        runs.sort(key=lambda r: r["fps_steady"] or 0)
        results[mode] = {"median": runs[len(runs) // 2], "runs": runs}
        m = runs[len(runs) // 2]
        print(
            f"{mode:9s} workers={m['workers']} frames={m['frames']} startup={m['startup_s']:.2f}s "
            f"steady={m['fps_steady'] or 0:.2f} fps end-to-end={m['fps_end_to_end']:.2f} fps",
            flush=True,
        )
    _add_efficiency(results)
    doc = {
        "benchmark": "scaling",
        "synthetic": args.synthetic,
        "work_ms": args.work_ms if args.synthetic else None,
        "data": None if args.synthetic else str(args.data),
        "metadata": metadata(),
        "results": results,
    }
    text = json.dumps(doc, indent=2)
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(text + "\n")
    _print_table(results)
    return 0


if __name__ == "__main__":
    sys.exit(main())
