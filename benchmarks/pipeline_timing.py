"""Per-frame time split into load, render, match and homography on the shared real datasets.

Writes reports/pipeline_timing.md. Usage: python benchmarks/pipeline_timing.py [--frames N]
"""

from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path

import numpy as np
from _common import REPORTS, command_line, machine, md_table, shared_data

from pgt_check.config import RunConfig
from pgt_check.io import read_trajectory
from pgt_check.measure import FrameChecker
from pgt_check.verdict import apply_verdicts

STAGES = ("t_load_s", "t_render_s", "t_match_s", "t_homography_s", "time_s")


def bench(name: str, traj_path: Path, mesh: Path, n: int, matcher: str) -> list[object]:
    traj = read_trajectory(traj_path)
    frames = list(traj.frames)[:n]
    cfg = RunConfig.from_dict({"input": {"trajectory": str(traj_path), "mesh": str(mesh)},
                               "match": {"method": matcher}, "enhance": {"mode": "never"}})
    checker = FrameChecker(cfg)
    t = time.perf_counter()
    _ = checker.renderer
    _ = checker.matcher
    setup = time.perf_counter() - t
    checker.measure(frames[0])  # warm-up (shader compile, first allocation)
    recs = apply_verdicts([checker.measure(f) for f in frames], cfg)
    checker.close()
    row: list[object] = [name, matcher, len(recs), f"{recs[0]['width']}x{recs[0]['height']}",
                         f"{recs[0]['match_width']}x{recs[0]['match_height']}", round(setup, 2)]
    for key in STAGES:
        vals = [r[key] for r in recs if r.get(key) is not None]
        row.append(f"{1000 * statistics.median(vals):.0f} / {1000 * np.percentile(vals, 90):.0f}")
    return row


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--frames", type=int, default=30)
    args = ap.parse_args()
    data = shared_data()
    rows = []
    for matcher in ("sift", "orb", "akaze"):
        rows.append(bench("7scenes_redkitchen", data / "7scenes_redkitchen/trajectories.txt",
                          data / "7scenes_redkitchen/mesh.ply", args.frames, matcher))
        rows.append(bench("sceaux_castle", data / "sceaux_castle/trajectories.txt",
                          data / "sceaux_castle/mesh.ply", args.frames, matcher))
    header = ["dataset", "matcher", "frames", "photo", "match size", "setup s",
              "load ms (median / p90)", "render ms", "match ms", "homography ms", "total ms"]
    text = "\n".join([
        "# Pipeline timing per frame (raw path, no enhancement)",
        "",
        f"Machine: {machine()}. Command: `{command_line()}`.",
        "Medians and 90th percentiles over the frames after one warm-up frame; 'setup' is mesh "
        "load + GL context + matcher construction, paid once per run (per worker).",
        "Render and match run at the matching resolution (longest side 640 px by default); the "
        "corner error is reported in original photo pixels.",
        "",
        md_table(header, rows),
        "",
    ])
    REPORTS.mkdir(exist_ok=True)
    (REPORTS / "pipeline_timing.md").write_text(text)
    print(text)


if __name__ == "__main__":
    main()
