"""The whole pipeline on textureless scenes with the edge settings before and after issue #29.

Per dataset, the given trajectory, a copy with independent errors on 40 % of the frames
(1-4 deg, 2-8 % of the scene depth; neighbours too) and a copy moved as a whole by 2 deg + 4 %
of the scene depth are checked end to end (``FrameChecker`` + ``judge_run``, as the CLI does),
once with the edge settings before #29 (``decision = support``, ``select_model = never``) and
once with the defaults (``decision = either``, ``select_model = fallback``). Reported: PASS share
on the given poses (verified share), per-frame ROC-AUC on the injected errors (score: the corner
error of the path the verdict rests on, and the ``corner_error_px`` column), flagged share of the perturbed frames
and of the clean ones, the registration check's status on the given and the moved copy
(whether the run-level checks got enough frames), the registration estimate of the moved
copy, and seconds per frame.

    PYTHONPATH=. PGT_SHARED_DATA=/work/shared/data nice -n 10 python benchmarks/edge_pipeline.py \
        [--frames 30] [--datasets tsdf,boxes,castle,7s-colourless]

Writes reports/edge_pipeline.md and reports/edge_pipeline.json.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

import numpy as np
from _common import REPORTS, command_line, machine, md_table, shared_data
from shared_errors import (
    CACHE,
    REMOVE_CALIBRATION,
    _subset,
    cases,
    evaluate,
    measure,
    scene_depth,
)

from pgt_check.io import read_trajectory

SETTINGS = {
    "before #29 (support, fixed homography)": {"decision": "support", "select_model": "never"},
    "defaults (either, fallback model)": {},
}
CASES = ("given", "per-frame", "moved 2deg+4%")


def datasets(names: list[str], n: int, tmp: Path) -> dict[str, tuple]:
    out = {}
    for name in names:
        if name == "tsdf":
            from pgt_eval import make_tsdf_scene

            traj = read_trajectory(make_tsdf_scene(tmp / "tsdf", n))
            out[name] = (traj, tmp / "tsdf" / "tsdf.ply", {})
        elif name == "boxes":
            from pgt_eval import textureless_scene

            traj, mesh = textureless_scene(tmp / "boxes", n)
            out[name] = (traj, mesh, {})
        elif name == "castle":
            r = shared_data() / "sceaux_castle"
            out[name] = (read_trajectory(r / "trajectories.txt"), r / "mesh.ply", {})
        elif name == "7s-colourless":
            r = shared_data() / "7scenes_redkitchen"
            out[name] = (_subset(read_trajectory(r / "trajectories.txt"), n), r / "mesh.ply",
                         {"render": {"shading": "shaded"}, **REMOVE_CALIBRATION})
        else:
            raise SystemExit(f"unknown dataset {name!r}")
    return out


def run(name: str, traj, mesh: Path, cfgd: dict) -> list[dict]:
    rows = []
    for label, edges in SETTINGS.items():
        cfg_e = {**cfgd, "edges": edges} if edges else dict(cfgd)
        key = f"pipe-{name}-{'old' if edges else 'new'}"
        _, ms0, _ = measure(traj, mesh, cfg_e, f"{key}-given")
        depth = scene_depth(ms0)
        for case, (t, truth) in cases(traj, depth).items():
            if case not in CASES:
                continue
            c_cfg, c_ms, tpf = measure(t, mesh, cfg_e, f"{key}-{case}")
            row = evaluate(case, truth, c_ms, c_cfg)
            row.update(dataset=name, setting=label, s_per_frame=tpf,
                       edge_methods=sorted({m.edges.method for m in c_ms if m.edges}))
            if truth.get("all"):
                row["true_deg"], row["true_t"] = truth.get("deg"), truth.get("t")
            rows.append(row)
            print(json.dumps({k: v for k, v in row.items() if "correction" not in k}), flush=True)
    return rows


def _pass_share(r: dict) -> str:
    v = r["verdicts"]
    n = sum(v.values())
    return f"{v.get('PASS', 0)}/{n} ({v.get('PASS', 0) / n:.0%})" if n else ""


def _f(x, spec=".2f") -> str:
    return "" if x is None or (isinstance(x, float) and not np.isfinite(x)) else format(x, spec)


def write(rows: list[dict], frames: int) -> None:
    (REPORTS / "edge_pipeline.json").write_text(json.dumps(rows, indent=1, default=str))
    table = []
    for ds in dict.fromkeys(r["dataset"] for r in rows):
        for label in SETTINGS:
            by = {r["case"]: r for r in rows if r["dataset"] == ds and r["setting"] == label}
            g, pf, mv = (by.get(c) for c in CASES)
            if g is None:
                continue
            table.append([
                ds, label, _pass_share(g), g.get("registration", ""),
                f"{_f(pf.get('verdict_auc'))} / {_f(pf.get('frame_auc'))}" if pf else "",
                pf.get("flagged_bad", "") if pf else "", pf.get("flagged_good", "") if pf else "",
                mv["flagged"] if mv else "", mv.get("registration", "") if mv else "",
                (f"{_f(mv.get('reg_deg'))} deg / {_f(mv.get('reg_t'), '.3f')} "
                 f"(true {mv.get('true_deg')} / {_f(mv.get('true_t'), '.3f')})") if mv else "",
                _f(g.get("s_per_frame")),
            ])
    lines = [
        "# The edge path end to end: settings before and after issue #29\n",
        f"Command: `{command_line()}`\n",
        f"Machine: {machine()}. Up to {frames} frames per dataset (castle has 10).\n",
        (__doc__ or "").split("\n\n")[1].replace("\n", " ") + "\n",
        md_table(["dataset", "edge settings", "PASS given", "registration (given)",
                  "per-frame AUC (deciding path / corner_error_px)", "per-frame: flagged bad",
                  "per-frame: flagged clean",
                  "moved: flagged", "moved: registration", "moved: estimate",
                  "s/frame (given)"], table),
    ]
    (REPORTS / "edge_pipeline.md").write_text("\n".join(lines) + "\n")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    ap.add_argument("--frames", type=int, default=30)
    ap.add_argument("--datasets", default="tsdf,boxes,castle,7s-colourless")
    ap.add_argument("--from-json", action="store_true",
                    help="only rewrite reports/edge_pipeline.md from its .json")
    a = ap.parse_args(argv)
    if a.from_json:
        write(json.loads((REPORTS / "edge_pipeline.json").read_text()), a.frames)
        return 0
    rows: list[dict] = []
    for old in CACHE.glob("pipe-*.json"):  # measured with an older working tree
        old.unlink()
    with tempfile.TemporaryDirectory() as tmp:
        for name, (traj, mesh, cfgd) in datasets(a.datasets.split(","), a.frames,
                                                 Path(tmp)).items():
            rows += run(name, traj, mesh, cfgd)
            write(rows, a.frames)
    return 0


if __name__ == "__main__":
    sys.exit(main())
