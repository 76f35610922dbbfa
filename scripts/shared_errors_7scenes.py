"""Real-data check of the run-level shared-error estimators on 7-Scenes redkitchen.

Builds absolute evidence for N frames (render at the checked pose, SIFT render<->photo, render
keypoints lifted with the render depth; raw matches, outliers left to the estimator), then runs
registration / calibration / drift on:
  * the given trajectory (depth-camera D-SLAM poses: RGB photos sit ~0.67 deg + 2.6 cm off),
  * the visloc RGB-corrected D-SLAM poses (trajectories_dslam_rgb.txt),
  * the given trajectory moved by 2 deg about its centroid + 4 % of the median scene depth
    (re-rendered at the moved poses).

Usage: PYTHONPATH=. python scripts/shared_errors_7scenes.py [--frames 20] [--json out.json]
Data: $PGT_SHARED_DATA (default ../shared/data).
"""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

import numpy as np

from pgt_check.geometry.pnp import lift_keypoints
from pgt_check.geometry.shared_errors import (
    FrameEvidence,
    estimate_calibration,
    estimate_drift,
    estimate_registration,
)
from pgt_check.geometry.transforms import axis_angle_to_rotmat
from pgt_check.io import read_trajectory
from pgt_check.io.images import load_image
from pgt_check.match import make_matcher
from pgt_check.render import load_mesh, make_renderer


def build_evidence(frames, poses, renderer, matcher) -> list[FrameEvidence]:
    out = []
    for i, (f, pose) in enumerate(zip(frames, poses, strict=True)):
        render = renderer.render(f.camera, pose)
        photo = load_image(f.image_file)
        m = matcher.match(render.rgb, photo, mask0=render.coverage)
        valid, pts = lift_keypoints(m.kpts0, render.depth, f.camera, pose)
        out.append(
            FrameEvidence(
                f.frame_id,
                i,
                "rgb",
                pose,
                f.camera.K,
                f.camera.width,
                f.camera.height,
                m.kpts1[valid],
                pts[valid],
            )
        )
    return out


SAVE: Path | None = None


def summarise(slug: str, name: str, ev: list[FrameEvidence], threshold_px: float) -> dict:
    if SAVE is not None:
        SAVE.mkdir(parents=True, exist_ok=True)
        (SAVE / f"{slug}.json").write_text(json.dumps([e.to_json() for e in ev]))
    t0 = time.perf_counter()
    reg = estimate_registration(ev)
    reg_none = estimate_registration(ev, calibration="none")
    cal = estimate_calibration(ev)["rgb"]
    drift = estimate_drift(ev, threshold_px=threshold_px)
    dt = time.perf_counter() - t0
    print(
        f"\n== {name}: {len(ev)} frames, {sum(len(e.pts2d) for e in ev)} correspondences, "
        f"estimators {dt:.2f} s"
    )
    for label, r in (("registration (joint calib)", reg), ("registration (world only)", reg_none)):
        if not r.success:
            print(f"{label}: failed ({r.reason})")
            continue
        print(
            f"{label}: angle {r.angle_deg:.3f} deg CI {np.round(r.angle_deg_ci, 3).tolist()}, "
            f"t {100 * r.translation:.2f} cm ({100 * r.translation_frac:.2f} % of depth "
            f"{r.median_scene_depth:.2f} m) CI {np.round(np.multiply(r.translation_ci, 100), 2).tolist()} cm, "
            f"effect {r.effect_px:.2f} px CI {np.round(r.effect_px_ci, 2).tolist()}, "
            f"inliers {r.n_inliers}/{r.n_points}, residual {r.residual_median_before:.2f}->"
            f"{r.residual_median_after:.2f} px, corr {r.max_correlation:.3f}, "
            f"ambiguous {r.ambiguous_with_calibration}, exceeds({threshold_px}) {r.exceeds(threshold_px)}"
        )
        if r.ambiguity:
            print(f"  ambiguous: {r.ambiguity}")
    if cal.success:
        print(
            f"calibration: rot {cal.equivalent_rotation_deg:.3f} deg CI "
            f"{np.round(cal.equivalent_rotation_deg_ci, 3).tolist()} rotvec "
            f"{np.round(cal.rotvec_deg, 3).tolist()} deg, pp shift "
            f"{np.round(cal.principal_point_shift_px, 2).tolist()} px, focal x{cal.focal_scale:.4f} "
            f"CI {np.round(cal.focal_scale_ci, 4).tolist()}, effect {cal.effect_px:.2f} px CI "
            f"{np.round(cal.effect_px_ci, 2).tolist()}, separable {cal.separable}, "
            f"exceeds {cal.exceeds(threshold_px)}"
        )
    else:
        print(f"calibration: failed ({cal.reason})")
    if drift.success:
        print(
            f"drift: segments {drift.segments} (rejected {drift.rejected_segments}), windows "
            f"{[(w.start, w.stop) for w in drift.windows]}, effects "
            f"{[round(w.estimate.effect_px, 2) for w in drift.windows]}, "
            f"lower bounds {[round(w.estimate.effect_px_ci[0], 2) for w in drift.windows]}"
        )
    else:
        print(f"drift: failed ({drift.reason})")
    return {
        "registration": reg.to_json(),
        "registration_world_only": reg_none.to_json(),
        "calibration": cal.to_json(),
        "drift": drift.to_json(),
        "seconds": dt,
    }


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--frames", type=int, default=20)
    ap.add_argument("--threshold-px", type=float, default=2.0)
    ap.add_argument("--json", type=Path)
    ap.add_argument("--save-evidence", type=Path, help="write the evidence here (JSON per set)")
    args = ap.parse_args()
    global SAVE
    SAVE = args.save_evidence
    data = Path(os.environ.get("PGT_SHARED_DATA", "../shared/data")) / "7scenes_redkitchen"
    traj = read_trajectory(data / "trajectories.txt", sensors=data / "sensors.txt")
    rgb = read_trajectory(data / "trajectories_dslam_rgb.txt", sensors=data / "sensors.txt")
    step = max(1, len(traj.frames) // args.frames)
    frames = list(traj.frames[::step][: args.frames])
    rgb_by_id = {f.frame_id: f for f in rgb.frames}
    renderer = make_renderer(load_mesh(data / "mesh.ply"))
    matcher = make_matcher("sift")
    results = {}
    try:
        ev = build_evidence(frames, [f.world_from_cam for f in frames], renderer, matcher)
        results["given"] = summarise(
            "given", "given (depth-camera D-SLAM poses)", ev, args.threshold_px
        )
        poses_rgb = [rgb_by_id[f.frame_id].world_from_cam for f in frames]
        ev_rgb = build_evidence(frames, poses_rgb, renderer, matcher)
        results["dslam_rgb"] = summarise(
            "dslam_rgb", "visloc RGB D-SLAM poses", ev_rgb, args.threshold_px
        )
        # move the whole trajectory: 2 deg about its centroid + 4 % of the median depth
        depth = results["given"]["registration"]["median_scene_depth"]
        centroid = np.mean([f.world_from_cam[:3, 3] for f in frames], axis=0)
        rng = np.random.default_rng(0)
        r = axis_angle_to_rotmat(rng.normal(size=3), 2.0)
        d = rng.normal(size=3)
        t = 0.04 * depth * d / np.linalg.norm(d)
        moved = []
        for f in frames:
            p = f.world_from_cam.copy()
            p[:3, :3] = r @ p[:3, :3]
            p[:3, 3] = r @ (p[:3, 3] - centroid) + centroid + t
            moved.append(p)
        print(f"\nmove: 2 deg, {100 * np.linalg.norm(t):.2f} cm (4 % of {depth:.2f} m)")
        ev_moved = build_evidence(frames, moved, renderer, matcher)
        results["moved"] = summarise(
            "moved", "given, moved 2 deg + 4 % depth", ev_moved, args.threshold_px
        )
    finally:
        renderer.close()
    if args.json:
        args.json.write_text(json.dumps(results, indent=1))


if __name__ == "__main__":
    main()
