"""Correction accuracy on injected pose errors -> reports/corrections.md (+ .json).

For each scene, ``--frames`` frames (evenly spaced) get a random pose error (rotation uniform in
``--rot`` degrees about a random axis, camera-centre shift uniform in ``--trans`` x the frame's
median render depth, random direction; seeded). Each perturbed frame is measured as a run
would (default settings: SIFT at 320 px, enhance auto with reproject, PnP), then corrected
(``pgt_check.correct.frames.correct_frame``: 3 rounds of render -> raw match at 640 px -> PnP
from the measurement's PnP estimate). Reported: share of corrected poses within 0.1 deg AND
1 % of the median scene depth of the reference pose, the error medians, and the baseline: the
same correction started from the reference pose itself (where the renders' own fixed point
lies; on real data the reference poses are not perfect).

Reference poses: sample scene: the generated truth (its trajectories.txt with the documented
perturbations of perturbed.txt undone); 7-Scenes: trajectories.txt (D-SLAM; the mesh was fused
with these poses); castle: trajectories.txt (OpenMVS; the mesh's own reconstruction).

Each correction also uses the reference frames the run would vouch for (the frame's picks; the
other frames carry the reference poses). Issue #38 adds: within 30 % of the injected error
(rotation and centre), of the reference pose and of the photo-consistent pose.

    python benchmarks/corrections.py [--frames 16] [--scenes sample,7scenes,castle] [--out NAME]

(``7scenes_train``: the 800 held-out 7-Scenes frames, ``../shared/data/7scenes_redkitchen_train``,
with 7-Scenes' mesh; not in the default list.)
"""

from __future__ import annotations

import argparse
import json
import sys
import time

import numpy as np
from _common import REPO, REPORTS, command_line, machine, md_table, shared_data

from pgt_check.config import RunConfig
from pgt_check.types import Trajectory


def sample_truth() -> tuple[Trajectory, str, dict]:
    """The sample scene with its documented perturbations undone."""
    from pgt_check.geometry.transforms import axis_angle_to_rotmat, invert_rigid, make_rigid
    from pgt_check.io import read_trajectory

    scene = REPO / "sample_data" / "scene"
    traj = read_trajectory(scene / "trajectories.txt")
    offsets = {}
    for line in (scene / "perturbed.txt").read_text().splitlines():
        if line.startswith("#") or not line.strip():
            continue
        f = [x.strip() for x in line.split(",")]
        rot = axis_angle_to_rotmat(np.array(list(map(float, f[2:5]))), float(f[1]))
        offsets[f[0]] = make_rigid(rot, np.array(list(map(float, f[5:8]))))
    frames = [fr.with_pose(fr.world_from_cam @ invert_rigid(offsets[fr.frame_id]))
              if fr.frame_id in offsets else fr for fr in traj]
    truth = Trajectory(tuple(frames), traj.source, traj.format, dict(traj.metadata))
    return truth, str(scene / "mesh.glb"), {}


def scenes(names: list[str]) -> dict[str, tuple[Trajectory, str, dict]]:
    from pgt_check.io import read_trajectory

    out = {}
    if "sample" in names:
        out["sample"] = sample_truth()
    if "7scenes" in names:
        d = shared_data() / "7scenes_redkitchen"
        out["7scenes"] = (read_trajectory(d / "trajectories.txt", sensors=d / "sensors.txt"),
                          str(d / "mesh.ply"), {})
    if "7scenes_train" in names:
        # the 800 held-out frames of the same recording, in the world of 7-Scenes' mesh
        # (the data README, section 3): frames no rule or constant was fitted on
        d = shared_data() / "7scenes_redkitchen_train"
        out["7scenes_train"] = (read_trajectory(d / "trajectories.txt", sensors=d / "sensors.txt"),
                                str(shared_data() / "7scenes_redkitchen" / "mesh.ply"), {})
    if "castle" in names:
        d = shared_data() / "sceaux_castle"
        out["castle"] = (read_trajectory(d / "trajectories.txt", sensors=d / "sensors.txt"),
                         str(d / "mesh.ply"), {"render": {"shading": "shaded"}})
    return out


def perturbed(checker, frame, rot, trans, rng):
    """``frame`` with a random pose error (module docstring): rotation uniform in ``rot`` deg
    about a random axis, centre shift uniform in ``trans`` x the frame's median render depth
    (rendered by ``checker``'s renderer at a quarter of the size). Returns (the wrong frame,
    rotation deg, shift, that depth)."""
    from pgt_eval import perturb_pose

    depth = checker.renderer.render(frame.camera.scaled(0.25), frame.world_from_cam).depth
    med = float(np.median(depth[depth > 0]))
    r = float(rng.uniform(*rot))
    t = float(rng.uniform(*trans)) * med
    return frame.with_pose(perturb_pose(frame.world_from_cam, r, t, rng)), r, t, med


def run_scene(name, truth, mesh, extra, n_frames, rot, trans, seed):
    from pgt_check.config import merge
    from pgt_check.correct.frames import CORRECTION_REFERENCES, correct_frame
    from pgt_check.geometry.transforms import pose_difference
    from pgt_check.measure import FrameChecker, pick_references

    cfg = RunConfig.from_dict(merge({"input": {"mesh": mesh}}, extra))
    rng = np.random.default_rng(seed)
    idx = np.linspace(0, len(truth) - 1, min(n_frames, len(truth))).round().astype(int)
    checker = FrameChecker(cfg)
    res = []
    try:
        for i in idx:
            f = truth.frames[int(i)]
            bad, r, t, med = perturbed(checker, f, rot, trans, rng)
            frames = list(truth.frames)
            frames[int(i)] = bad
            traj = Trajectory(tuple(frames), truth.source, truth.format)
            checker.references = pick_references(traj, [bad], cfg)
            # the other frames are the reference poses: every neighbour is vouched for
            refs = checker.references.get(bad.frame_id, ())[:CORRECTION_REFERENCES]
            t0 = time.perf_counter()
            m = checker.measure(bad)
            c = correct_frame(checker, bad, m, cfg.correct, references=refs)
            secs = time.perf_counter() - t0
            base = correct_frame(checker, f, None, cfg.correct, references=refs)  # from the reference pose
            row = {"frame_id": f.frame_id, "inj_rot_deg": r, "inj_t": t, "depth": med,
                   "success": c.success, "applied": c.applied, "start": c.start,
                   "rounds": c.rounds, "seconds": secs,
                   "pnp_rot_err_deg": None, "pnp_t_err": None}
            if m.pose is not None and m.pose.world_from_cam is not None:
                dt, dr = pose_difference(f.world_from_cam, np.asarray(m.pose.world_from_cam))
                row.update(pnp_rot_err_deg=dr, pnp_t_err=dt)
            if c.success:
                dt, dr = pose_difference(f.world_from_cam, c.pose)
                row.update(rot_err_deg=dr, t_err=dt, t_err_rel=dt / med,
                           sigma_rot_deg=c.sigma_rot_deg, sigma_t=c.sigma_t,
                           corner_error_px=c.corner_error_px)
            if base.success:
                dt, dr = pose_difference(f.world_from_cam, base.pose)
                row.update(base_rot_deg=dr, base_t_rel=dt / med)
            # issue #38: within 30 % of the injected error, of the reference pose and of the
            # photo-consistent one (the correction started from the reference pose)
            if c.success:
                dt, dr = pose_difference(f.world_from_cam, c.pose)
                row["within30_given"] = bool(dr <= 0.3 * r and dt <= 0.3 * t)
                if base.success:
                    dt, dr = pose_difference(base.pose, c.pose)
                    row["within30_pc"] = bool(dr <= 0.3 * r and dt <= 0.3 * t)
            res.append(row)
            print(name, {k: (round(v, 4) if isinstance(v, float) else v)
                         for k, v in row.items()}, flush=True)
    finally:
        checker.close()
    return res


def within(rows, rot_key, t_key, rot_tol=0.1, t_tol=0.01):
    ok = [r for r in rows if r.get(rot_key) is not None and r[rot_key] <= rot_tol
          and r[t_key] <= t_tol]
    return len(ok)


def med(rows, key):
    v = [r[key] for r in rows if r.get(key) is not None]
    return float(np.median(v)) if v else float("nan")


def main() -> int:
    p = argparse.ArgumentParser()
    p.add_argument("--frames", type=int, default=16)
    p.add_argument("--scenes", default="sample,7scenes,castle")
    p.add_argument("--rot", type=float, nargs=2, default=(1.0, 4.0))
    p.add_argument("--trans", type=float, nargs=2, default=(0.01, 0.05))
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", default="corrections", help="report name in reports/ (.md, .json)")
    args = p.parse_args()
    all_rows = {}
    for name, (truth, mesh, extra) in scenes(args.scenes.split(",")).items():
        all_rows[name] = run_scene(name, truth, mesh, extra, args.frames, args.rot, args.trans,
                                   args.seed)
    table = []
    for name, rows in all_rows.items():
        n = len(rows)
        for r in rows:
            r["t_err_rel"] = r.get("t_err_rel")
            if r.get("pnp_t_err") is not None:
                r["pnp_t_rel"] = r["pnp_t_err"] / r["depth"]
        table.append([
            name, n, f"{med(rows, 'inj_rot_deg'):.2f} / {med(rows, 'inj_t') / med(rows, 'depth'):.1%}",
            f"{sum(r['success'] for r in rows)} / {sum(r['applied'] for r in rows)}",
            f"{within(rows, 'rot_err_deg', 't_err_rel')}/{n}",
            f"{within(rows, 'pnp_rot_err_deg', 'pnp_t_rel')}/{n}",
            f"{within(rows, 'base_rot_deg', 'base_t_rel')}/{n}",
            f"{med(rows, 'rot_err_deg'):.3f} / {med(rows, 't_err_rel'):.2%}",
            f"{med(rows, 'sigma_rot_deg'):.3f}",
            f"{med(rows, 'base_rot_deg'):.3f} / {med(rows, 'base_t_rel'):.2%}",
            f"{sum(bool(r.get('within30_given')) for r in rows)}/{n}",
            f"{sum(bool(r.get('within30_pc')) for r in rows)}/{n}",
            f"{med(rows, 'seconds'):.1f}",
        ])
    header = ["scene", "frames", "injected median (deg / % depth)", "succeeded / applied",
              "corrected within 0.1 deg & 1 %", "single PnP within", "baseline within",
              "median error after (deg / % depth)", "median sigma_rot (deg)",
              "baseline median (deg / % depth)", "within 30 % of the injected error (reference pose)",
              "within 30 % (photo-consistent: the baseline's pose)", "s / frame"]
    text = "\n".join([
        "# Pose corrections on injected errors",
        "",
        (__doc__ or "").split("\n\n    python")[0].strip(),
        "",
        f"Machine: {machine()}. Command: `{command_line()}`.",
        "",
        md_table(header, table),
        "",
        "Columns: *corrected within*: share of frames whose corrected pose is within 0.1 deg "
        "and 1 % of the median render depth of the reference pose; *single PnP within*: the "
        "same for the measurement's one-shot PnP estimate; *baseline*: the correction started "
        "from the reference pose (how far the render/photo fixed point lies from the "
        "reference). Per-frame rows: reports/corrections.json.",
        "",
    ])
    REPORTS.mkdir(exist_ok=True)
    (REPORTS / f"{args.out}.json").write_text(json.dumps(all_rows, indent=1, default=str) + "\n")
    (REPORTS / f"{args.out}.md").write_text(text)
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
