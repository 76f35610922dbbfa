"""Many frames wrong: the leave-one-scene-out per-frame protocol at 50 % (issue 38:
"unbiased with up to 40 % of frames carrying their own errors (design for 50 %)"), or at any
``--fraction`` and ``--frames`` (the issue's item 1: 57 frames of a textureless scan, 40 %
wrong, ``--remove-calibration``).

For every shared scene (``--scenes``; the generated scans of ``scenes_loso.py`` too), the same
frames as ``scenes_loso.py`` (30 by default); 50 % of them wrong in contiguous runs of 2-4
frames (``pgt_eval.perturb_runs``, ``--seed`` 4; a wrong frame's neighbours are wrong too), each
0.5-4 deg + 1-8 % of the scene depth; judged with the defaults (7-Scenes as the
trusted-calibration workflow does: ``--calibration-from`` its given run judged with
``--remove-calibration``), or with ``--remove-calibration`` on every scene. ``--camera-offset``:
every pose also carries one camera-frame offset (a wrong calibration or hand-eye transform,
as motion-capture poses of a camera have), which ``--remove-calibration`` must find beside the
wrong frames. ``--as-run``: the
reference pass and the separation probes a run adds after its main pass
(``shared_errors.as_run``). Prints one JSON line per scene: flagged frames, verdicts, the
registration check, frames left out of the pooled fits, per-frame AUC, wrong / correct frames
flagged; each line is also kept in reports/scenes_loso_half.json (by scene, frames, fraction,
seed and judge; a re-run replaces its row) and the table in reports/scenes_loso_half.md.
Measurements are cached as ``scenes_loso.py``'s are.

    python benchmarks/scenes_loso_half.py [--scenes a,b] [--fraction 0.5] [--frames 30]
        [--seed 4] [--camera-offset DEG REL]
        [--remove-calibration [--calibration-translation]] [--as-run] [--reuse-measurements]
        [--report-only]
"""

from __future__ import annotations

import argparse
import json
import time

import scenes_loso as L
import shared_errors
from _common import REPORTS, command_line, machine, md_table
from shared_errors import as_run, measure
from shared_errors_cases import evaluate, scene_depth

from pgt_check.verdict import judge_run
from pgt_eval import perturb_runs


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--scenes", default=",".join(L.SCENES))
    p.add_argument("--fraction", type=float, default=0.5)
    p.add_argument("--frames", type=int, default=30)
    p.add_argument("--seed", type=int, default=4, help="of the injected errors")
    p.add_argument("--camera-offset", type=float, nargs=2, default=None, metavar=("DEG", "REL"),
                   help="every pose also carries one camera-frame offset (a calibration "
                        "error, as motion-capture poses of a camera have): DEG about a random "
                        "axis + REL x the scene depth in a random direction")
    p.add_argument("--remove-calibration", action="store_true",
                   help="judge every scene with --remove-calibration")
    p.add_argument("--calibration-translation", action="store_true",
                   help="with --remove-calibration: the calibration also fits a camera-frame "
                        "translation (pgt-check --calibration-translation)")
    p.add_argument("--as-run", action="store_true",
                   help="with the reference pass and probes a run adds (shared_errors.as_run)")
    p.add_argument("--reuse-measurements", action="store_true",
                   help="judge the newest cached measurements (as scenes_loso.py)")
    p.add_argument("--report-only", action="store_true",
                   help="write the Markdown from reports/scenes_loso_half.json")
    a = p.parse_args(argv)
    if a.report_only:
        write_report(json.loads(JSON.read_text()))
        return 0
    shared_errors.REUSE_MEASUREMENTS = a.reuse_measurements
    L.FRAMES = a.frames  # the cache keys' frame count (``scenes_loso._prefix``)
    for name in [s for s in a.scenes.split(",") if s]:
        traj, mesh, cfgd = L.load_scene(name, a.frames)
        _, given, _ = measure(traj, mesh, cfgd, f"{L._prefix(name)}-given")
        depth = scene_depth(given)
        base = traj if a.camera_offset is None else camera_offset(traj, *a.camera_offset, depth)
        bad, inj = perturb_runs(base, a.fraction, (0.5, 4.0), (0.01 * depth, 0.08 * depth),
                                seed=a.seed)
        t0 = time.perf_counter()
        case = ("half" if a.fraction == 0.5 else f"wrong{a.fraction:g}") + (
            "" if a.seed == 4 else f"-s{a.seed}") + (
            "" if a.camera_offset is None else "-cam{:g}-{:g}".format(*a.camera_offset))
        _, ms, _ = measure(bad, mesh, cfgd, f"{L._prefix(name)}-{case}")
        judge = cfgd
        if a.remove_calibration:
            judge = {**cfgd, "run_checks": {"remove_calibration": True,
                                            "calibration_translation": a.calibration_translation}}
        elif name.startswith("7scenes"):
            judge = L.trusted_judges(name, given, mesh, cfgd)[L.CAL_FROM]
        cfg = L._cfg(mesh, judge)
        probes = None
        if a.as_run:
            ms, probes = as_run(bad, ms, cfg, f"{L._prefix(name)}-{case}-"
                                + ("rm" if a.remove_calibration else "default")
                                + ("-ct" if a.calibration_translation else ""))
        row = evaluate("per-frame", {"labels": {q.frame_id for q in inj}}, ms, cfg, probes)
        shared = judge_run(ms, cfg, probes).shared
        left = (shared.summary().get("frame_screen", {}).get("n_left_out")
                if shared is not None else None)
        keep = {k: row.get(k) for k in ("flagged", "verdicts", "registration", "reg_px",
                                        "drift", "calibration", "frame_auc", "flagged_bad",
                                        "flagged_good")}
        judged = ("--remove-calibration" if a.remove_calibration else
                  L.CAL_FROM if name.startswith("7scenes") else "defaults")
        if a.remove_calibration and a.calibration_translation:
            judged += " --calibration-translation"
        if a.camera_offset is not None:
            judged += " (camera offset {:g} deg + {:g} x depth)".format(*a.camera_offset)
            keep["calibration_estimate"] = (shared.summary().get("calibration")
                                            if shared is not None else None)
        line = {"scene": name, "frames": len(traj), "fraction": a.fraction, "seed": a.seed,
                "judge": judged + (", as a run" if a.as_run else ", main pass"),
                "wrong": len(inj), "left_out": left, "s": round(time.perf_counter() - t0),
                **keep}
        print(json.dumps(line), flush=True)
        record(line)
    return 0


def camera_offset(traj, deg: float, rel: float, depth: float, seed: int = 11):
    """Every pose times one ``cam_from_offset_cam``: ``deg`` about a random axis and ``rel`` x
    ``depth`` in a random direction, in the camera frame (what a wrong camera calibration or
    hand-eye transform does to a whole trajectory)."""
    import numpy as np

    from pgt_check.geometry.transforms import axis_angle_to_rotmat
    from pgt_check.types import Trajectory

    rng = np.random.default_rng(seed)
    axis, shift = rng.normal(size=3), rng.normal(size=3)
    off = np.eye(4)
    off[:3, :3] = axis_angle_to_rotmat(axis / np.linalg.norm(axis), deg)
    off[:3, 3] = rel * depth * shift / np.linalg.norm(shift)
    return Trajectory([f.with_pose(f.world_from_cam @ off) for f in traj.frames], traj.source,
                      traj.format)


JSON = REPORTS / "scenes_loso_half.json"
KEY = ("scene", "frames", "fraction", "seed", "judge")


def record(line: dict) -> None:
    """Keep ``line`` (replacing a row with the same ``KEY``) and write the Markdown table."""
    doc = json.loads(JSON.read_text()) if JSON.is_file() else {"rows": [], "notes": []}
    rows = [r for r in doc["rows"] if any(r.get(k) != line[k] for k in KEY)]
    rows.append({**line, "command": command_line(), "machine": machine()})
    doc["rows"] = rows  # the hand-written reading ("notes") is kept
    JSON.write_text(json.dumps(doc, indent=1) + "\n")
    write_report(doc)


def write_report(doc: dict) -> None:
    rows = doc["rows"]
    head = ["scene", "frames", "wrong (fraction, seed)", "judged", "per-frame AUC",
            "correct frames flagged", "wrong frames flagged", "verdicts",
            "registration (px)", "drift", "calibration", "left out of the pooled fits"]
    table = [[r["scene"], r["frames"], f"{r['wrong']} ({r['fraction']:g}, {r['seed']})",
              r["judge"], f"{r['frame_auc']:.3f}" if r.get("frame_auc") is not None else "",
              r["flagged_good"], r["flagged_bad"],
              ", ".join(f"{k} {v}" for k, v in sorted(r["verdicts"].items())),
              f"{r['registration']} ({r['reg_px']:.2f})" if r.get("reg_px") is not None
              else str(r.get("registration")), r.get("drift"), r.get("calibration"),
              r.get("left_out")] for r in rows]
    cmds = sorted({f"`{r['command']}`; {r['machine']}" for r in rows})
    (REPORTS / "scenes_loso_half.md").write_text("\n".join(
        ["# Many frames wrong at once, neighbours too", "",
         (__doc__ or "").split("\n\n    python")[0].strip(), "",
         md_table(head, table), "", "Commands:", "", *[f"- {c}" for c in cmds], "",
         *doc.get("notes", [])]) + "\n")


if __name__ == "__main__":
    raise SystemExit(main())
