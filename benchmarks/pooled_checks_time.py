"""Time of the run-level checks against the trajectory length, with and without the point cap.

Usage: python benchmarks/pooled_checks_time.py RECORDS.jsonl cap|nocap K [K ...]

The stored measurements of one run (``OUT/records.jsonl``) are copied to K frames (new frame
ids, same poses and evidence) and ``run_shared_checks`` is timed on them in-process; ``nocap``
lifts ``verdict.shared.MAX_POOLED_POINTS``. Prints wall and CPU seconds and the registration
status and effect per K (the figures of reports/scaling.md, "the pooled fits take a bounded
number of points").
"""

from __future__ import annotations

import dataclasses
import json
import sys
import time

from _common import shared_data

import pgt_check.verdict.shared as shared
from pgt_check.config import RunConfig
from pgt_check.measure import FrameMeasurement


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    records, mode, sizes = argv[0], argv[1], [int(k) for k in argv[2:]]
    with open(records) as f:
        base = [FrameMeasurement.from_json(json.loads(ln)) for ln in f if ln.strip()]
    d = shared_data() / "7scenes_redkitchen"
    config = RunConfig.from_dict(
        {"input": {"trajectory": str(d / "trajectories.txt"), "mesh": str(d / "mesh.ply")}}
    )
    if mode == "nocap":
        shared.MAX_POOLED_POINTS = 10**9
    for k in sizes:
        ms = [dataclasses.replace(base[i % len(base)], frame_id=f"{i:06d}") for i in range(k)]
        t, c = time.perf_counter(), time.process_time()
        s = shared.run_shared_checks(ms, config).summary()
        reg = s["registration"]
        print(f"{mode} {k}: wall {time.perf_counter() - t:.1f} s, cpu {time.process_time() - c:.1f}"
              f" s, registration {reg['status']} {reg.get('effect_px')}, drift "
              f"{s['drift']['status']}", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
