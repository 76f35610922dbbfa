"""MaRINeR in the validator with the other paths, on colourless renders of every shared scene
(issue 37, item 4: "with MaRINeR alone and combined with the other paths").

``mariner_evidence.py`` scores the enhanced path alone. This script runs the whole per-frame
verdict (raw render, enhanced render, geometric edges; ``judge_run``) on ``--frames`` frames
evenly spaced along each scene, rendered *without colours* (``render.shading = shaded``; the
castle's mesh has none), on the given poses and on the whole trajectory moved by 1 deg + 2 % of
the camera path's span (as ``mariner_evidence.py``), with three enhancement settings:

* ``none``: ``--enhance never`` (raw and edge paths only);
* ``reproject``: the default (``--enhance auto --enhance-method reproject``);
* ``mariner``: ``--enhance auto --enhance-method mariner`` (the shipped weights, the run's scene
  check choosing decoder or matching-only base).

The same measurements are judged twice: frame by frame (``run_checks.enabled = false``: a
moved trajectory has to be flagged on each frame's own evidence) and as a default run judges
them (the run-level checks on: the registration check flags a moved trajectory as a whole).
Per scene and setting: correct frames verified (PASS on the given poses), moved frames flagged
(not PASS), the ROC-AUC of the headline corner error (the deciding evidence's; none = worst),
given vs moved, and seconds per frame. 7-Scenes' given poses are the depth camera's (a ~0.7
deg offset to the RGB photos, data README): its runs are judged as the documented
trusted-calibration workflow does (the given run with ``--remove-calibration``, the moved one
with ``--calibration-from`` the given run's summary); frame by frame the offset stays in every
frame's error.

    python benchmarks/mariner_in_validator.py [--frames 12] [--scenes a,b] [--settings a,b]

Writes reports/mariner_in_validator.md and .json.
"""

from __future__ import annotations

import argparse
import json
import math
import time

import numpy as np
from _common import REPORTS, command_line, machine, md_table
from mariner_evidence import scene_choice
from scenes_loso import CAL_FROM, SCENES, load_scene, trusted_judges

from pgt_check.config import RunConfig
from pgt_check.measure import FrameChecker, pick_references
from pgt_check.verdict import judge_run
from pgt_eval import move_trajectory, roc_auc, shared_transform

SETTINGS = {
    "none": {"mode": "never"},
    "reproject": {"mode": "auto", "method": "reproject"},
    "mariner": {"mode": "auto", "method": "mariner", "output": "auto"},
}


def _config(traj, mesh, shading: str, enhance: dict, run_checks: dict | None = None
            ) -> RunConfig:
    return RunConfig.from_dict({
        "input": {"trajectory": traj.source, "mesh": str(mesh)},
        "render": {"shading": shading},
        "enhance": enhance,
        "run_checks": run_checks or {},
    })


def _measured(traj, mesh, shading: str, enhance: dict) -> list:
    """The measurements of every frame of ``traj``."""
    cfg = _config(traj, mesh, shading, enhance)
    checker = FrameChecker(cfg, pick_references(traj, traj.frames, cfg))
    try:
        return [checker.measure(f) for f in traj.frames]
    finally:
        checker.close()


def _judged(name: str, traj, mesh, shading: str, enhance: dict, given_ms: list, moved_ms: list
            ) -> dict[str, tuple[list[dict], list[dict]]]:
    """(given rows, moved rows) judged frame by frame ("frame": run-level checks off) and as
    runs ("run"). 7-Scenes' runs are judged as the documented trusted-calibration workflow
    does (its given poses carry the depth camera's offset): the given run with
    ``--remove-calibration``, the moved one with ``--calibration-from`` the given run's
    summary (``scenes_loso.trusted_judges``)."""
    off = {"enabled": False}
    frame = (judge_run(given_ms, _config(traj, mesh, shading, enhance, off)).rows(),
             judge_run(moved_ms, _config(traj, mesh, shading, enhance, off)).rows())
    if name.startswith("7scenes"):
        judges = trusted_judges(name, given_ms, mesh, {})
        on_given = judges["--remove-calibration"]["run_checks"]
        on_moved = judges[CAL_FROM]["run_checks"]
    else:
        on_given = on_moved = {}
    run = (judge_run(given_ms, _config(traj, mesh, shading, enhance, on_given)).rows(),
           judge_run(moved_ms, _config(traj, mesh, shading, enhance, on_moved)).rows())
    return {"frame": frame, "run": run}


def _scene_choice(traj, mesh, shading: str) -> str:
    return scene_choice(_config(traj, mesh, shading, SETTINGS["mariner"]), traj)


def _score(rows: list[dict]) -> list[float]:
    """Headline corner error per frame (+inf where the frame has none)."""
    out = []
    for r in rows:
        e = r.get("corner_error_px")
        out.append(math.inf if e is None or e == "" or not math.isfinite(float(e)) else float(e))
    return out


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--frames", type=int, default=12)
    p.add_argument("--scenes", default=",".join(SCENES))
    p.add_argument("--settings", default=",".join(SETTINGS))
    p.add_argument("--out", default="mariner_in_validator")
    a = p.parse_args(argv)
    rows, results = [], []
    t_all = time.perf_counter()
    for name in [s for s in a.scenes.split(",") if s]:
        traj, mesh, _ = load_scene(name, a.frames)
        shading = "auto" if name == "sceaux_castle" else "shaded"
        centres = np.array([f.center for f in traj.frames])
        span = float(np.linalg.norm(centres.max(0) - centres.min(0)))
        moved = move_trajectory(traj, shared_transform(traj, 1.0, 0.02 * span, seed=1))
        for setting in [s for s in a.settings.split(",") if s]:
            t0 = time.perf_counter()
            enhance = SETTINGS[setting]
            choice = _scene_choice(traj, mesh, shading) if setting == "mariner" else None
            if choice is not None:  # made once on the given poses, kept for the moved run
                enhance = {**enhance, "output": choice}
            given_ms = _measured(traj, mesh, shading, enhance)
            moved_ms = _measured(moved, mesh, shading, enhance)
            judged = _judged(name, traj, mesh, shading, enhance, given_ms, moved_ms)
            sec = (time.perf_counter() - t0) / (2 * len(traj.frames))
            label = setting + (f" ({choice})" if choice else "")
            for judging in ("frame", "run"):
                given, mv = judged[judging]
                n = len(given)
                g, m = _score(given), _score(mv)
                verified = sum(r["verdict"] == "PASS" for r in given)
                flagged = sum(r["verdict"] != "PASS" for r in mv)
                auc = roc_auc(np.array(g + m), np.array([False] * n + [True] * len(m)))
                deciders: dict[str, int] = {}
                for r in given:
                    if r["verdict"] == "PASS":
                        key = r.get("decided_by") or "-"
                        deciders[key] = deciders.get(key, 0) + 1
                res = {"scene": name, "setting": setting, "judging": judging,
                       "scene_check": choice, "frames": n, "verified": verified,
                       "moved_flagged": flagged, "auc": auc, "pass_decided_by": deciders,
                       "s_per_frame": round(sec, 2),
                       "unverifiable_given": sum(r["verdict"] == "UNVERIFIABLE" for r in given)}
                results.append(res)
                print(json.dumps(res), flush=True)
                rows.append([name, label, "frame by frame" if judging == "frame" else "run",
                             f"{verified}/{n}", f"{res['unverifiable_given']}/{n}",
                             f"{flagged}/{len(m)}", f"{auc:.2f}",
                             ", ".join(f"{k} {v}" for k, v in sorted(deciders.items())) or "-",
                             f"{sec:.1f}"])
    out = {"command": command_line(), "machine": machine(),
           "minutes": round((time.perf_counter() - t_all) / 60, 1), "results": results}
    (REPORTS / f"{a.out}.json").write_text(json.dumps(out, indent=1))
    lines = [
        "# MaRINeR in the validator with the other paths, colourless renders (issue 37, item 4)",
        "",
        f"Command: `{command_line()}`  ",
        f"Machine: {machine()}; {out['minutes']} min.",
        "",
        "Verdicts (raw, enhanced and edge paths) on colourless "
        "renders, given poses and the trajectory moved by 1 deg + 2 % of the camera path's "
        "span. Settings: `none` = `--enhance never`; `reproject` = the default; `mariner` = "
        "`--enhance-method mariner` (the shipped weights; in brackets the output the run's "
        "scene check chose). Verified: PASS on the given poses; flagged: not PASS on the moved "
        "ones; judged frame by frame (run-level checks off) and as a run (the checks on: the "
        "registration check flags a moved trajectory as a whole); AUC: given vs moved frames "
        "by the headline corner error (none = worst; after the run-level corrections where the "
        "checks are on). "
        "Done-when (issue 37): >= 60 % verified, >= 90 % flagged, AUC >= 0.9. 7-Scenes' given "
        "poses carry the depth camera's ~0.7 deg offset: its runs are judged as the documented "
        "trusted-calibration workflow does (given run `--remove-calibration`, moved run "
        "`--calibration-from` it); frame by frame the offset stays in every frame's error.",
        "",
        md_table(["scene", "enhancement", "judged", "correct verified", "UNVERIFIABLE (given)",
                  "moved flagged", "AUC", "given PASS decided by", "s/frame"], rows),
        "",
    ]
    (REPORTS / f"{a.out}.md").write_text("\n".join(lines))
    print(REPORTS / f"{a.out}.md")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
