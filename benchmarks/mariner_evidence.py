"""MaRINeR alone as evidence on colourless renders, every shared scene (issue 37, item 4).

For each scene in the shared data folder, ``--frames`` frames evenly spaced along its
trajectory are rendered *without colours* (``render.shading = shaded``; the castle's mesh has
none) and checked with the enhanced path alone (``--enhance-method mariner --enhance always
--edges never``, ``--matcher`` (default SIFT), the default per-frame threshold), on the given poses and on the whole
trajectory moved by 1 deg + 2 % of the scene depth (the leave-one-scene-out benchmark's
``moved`` case). Per output of the shipped weights (the decoder, the matching-only base, and
the one the run's scene check picks): correct frames verified (enhanced corner error within
the threshold), moved frames flagged (not verified), and the per-frame ROC-AUC of the enhanced
corner error, given frames against moved ones (no homography = +inf).

    python benchmarks/mariner_evidence.py [--frames 12] [--scenes a,b]

Writes reports/mariner_evidence.md and .json.
"""

from __future__ import annotations

import argparse
import json
import math
import time

import numpy as np
from _common import REPORTS, command_line, machine, md_table
from scenes_loso import SCENES, load_scene

from pgt_check.config import RunConfig
from pgt_check.measure import FrameChecker, pick_references
from pgt_check.stages.scene_check import resolve_enhancer_output
from pgt_eval import move_trajectory, roc_auc, shared_transform

MATCHER = "sift"


def _config(traj, mesh, shading: str, output: str) -> RunConfig:
    return RunConfig.from_dict({
        "input": {"trajectory": traj.source, "mesh": str(mesh)},
        "render": {"shading": shading},
        "match": {"method": MATCHER},
        "enhance": {"mode": "always", "method": "mariner", "output": output},
        "edges": {"mode": "never"},
    })


def _errors(traj, mesh, shading: str, output: str) -> tuple[list[float], list[float]]:
    """(enhanced corner errors (+inf: no homography), thresholds) of every frame."""
    cfg = _config(traj, mesh, shading, output)
    checker = FrameChecker(cfg, pick_references(traj, traj.frames, cfg))
    try:
        ms = [checker.measure(f) for f in traj.frames]
    finally:
        checker.close()
    errs, thr = [], []
    for m in ms:
        e = m.enhanced.corner_error_px if m.enhanced is not None else None
        errs.append(math.inf if e is None or not m.enhanced.success else float(e))
        thr.append(cfg.verdict.threshold_for(m.width or 1, m.height or 1))
    return errs, thr


def scene_choice(cfg: RunConfig, traj) -> str:
    """The output ("model" or "base") the run's scene check picks for ``traj`` under ``cfg``
    (MaRINeR with ``enhance.output`` auto)."""
    checker = FrameChecker(cfg, pick_references(traj, traj.frames, cfg))
    try:
        return resolve_enhancer_output(cfg, traj.frames, checker.references,
                                       checker).enhance.output
    finally:
        checker.close()


def _scene_choice(traj, mesh, shading: str) -> str:
    return scene_choice(_config(traj, mesh, shading, "auto"), traj)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--frames", type=int, default=12)
    p.add_argument("--scenes", default=",".join(SCENES))
    p.add_argument("--matcher", default="sift", help="match.method of the run")
    p.add_argument("--out", default="mariner_evidence")
    a = p.parse_args(argv)
    global MATCHER
    MATCHER = a.matcher
    rows, results = [], []
    t_all = time.perf_counter()
    for name in [s for s in a.scenes.split(",") if s]:
        traj, mesh, _ = load_scene(name, a.frames)
        shading = "auto" if name == "sceaux_castle" else "shaded"
        centres = np.array([f.center for f in traj.frames])
        # the scene depth as the LOSO benchmark takes it would need a measured run: the camera
        # path's span stands in (the move is the same kind, 1 deg + 2 %)
        span = float(np.linalg.norm(centres.max(0) - centres.min(0)))
        moved = move_trajectory(traj, shared_transform(traj, 1.0, 0.02 * span, seed=1))
        t0 = time.perf_counter()
        choice = _scene_choice(traj, mesh, shading)
        for output in ("model", "base"):
            g, thr = _errors(traj, mesh, shading, output)
            mv, _ = _errors(moved, mesh, shading, output)
            n = len(g)
            verified = sum(e <= t for e, t in zip(g, thr, strict=True))
            flagged = sum(not e <= t for e, t in zip(mv, thr, strict=True))
            auc = roc_auc(np.array(g + mv), np.array([False] * n + [True] * n))
            res = {"scene": name, "output": output, "scene_check": choice, "frames": n,
                   "verified": verified, "moved_flagged": flagged, "auc": auc,
                   "median_given_px": float(np.median([x for x in g if math.isfinite(x)]))
                   if any(math.isfinite(x) for x in g) else None,
                   "with_h_given": sum(math.isfinite(x) for x in g)}
            results.append(res)
            print(json.dumps(res), flush=True)
            rows.append([name, output + (" (scene check's)" if output == choice else ""),
                         f"{verified}/{n}", f"{res['with_h_given']}/{n}", f"{flagged}/{n}",
                         f"{auc:.2f}", "-" if res["median_given_px"] is None
                         else f"{res['median_given_px']:.1f}"])
        print(f"{name}: {time.perf_counter() - t0:.0f} s", flush=True)
    out = {"command": command_line(), "machine": machine(),
           "minutes": round((time.perf_counter() - t_all) / 60, 1), "results": results}
    (REPORTS / f"{a.out}.json").write_text(json.dumps(out, indent=1))
    lines = [
        "# MaRINeR alone as evidence on colourless renders (issue 37, item 4)",
        "",
        f"Command: `{command_line()}`  ",
        f"Machine: {machine()}; {out['minutes']} min.",
        "",
        "Shipped weights, enhanced path alone (`--enhance-method mariner --enhance always "
        "--edges never`, matcher `" + a.matcher + "`), colourless renders, default per-frame threshold. Verified: "
        "corner error within the threshold on the given poses; flagged: not verified on the "
        "trajectory moved by 1 deg + 2 % of the camera path's span; AUC: given vs moved "
        "frames by the enhanced corner error (no homography = worst). Done-when: >= 60 % "
        "verified, >= 90 % flagged, AUC >= 0.9.",
        "",
        md_table(["scene", "output", "correct verified", "homography (given)",
                  "moved flagged", "AUC", "median corner error px (given)"], rows),
        "",
    ]
    (REPORTS / f"{a.out}.md").write_text("\n".join(lines))
    print(REPORTS / f"{a.out}.md")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
