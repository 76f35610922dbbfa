"""How well one photo pins its pose down, per scene: the rotation/translation trade-off.

For each frame of a scene's given run (the ``scenes_loso`` measurements, cached), at the mesh
points its absolute evidence saw: how many degrees the camera can turn while those points move
by only 1 px RMS in the photo, the translation chosen to compensate (the Schur complement of the
linearised projection), and how far it can move (in % of the scene depth) with the rotation
compensating. A correction's pose error is at least about this times the pixel bias of its
evidence (mesh colours misregistered with the geometry, a reference photo placed by a pose that
is itself off): where it is large, "within 30 % of the injected error" in degrees asks for
sub-pixel evidence, while the same correction can be within 30 % in the image
(``scenes_loso``'s image columns).

Writes reports/pose_trade_off.md (+ .json).

    python benchmarks/pose_trade_off.py [--scene 7scenes_redkitchen ...] [--shaded]
"""

from __future__ import annotations

import argparse
import json

import numpy as np
import scenes_loso
import shared_errors
from _common import REPORTS, command_line, machine, md_table
from shared_errors import measure
from shared_errors_cases import scene_depth

JSON = REPORTS / "pose_trade_off.json"
MD = REPORTS / "pose_trade_off.md"


def trade_off(pts_cam: np.ndarray, intrinsics: tuple[float, float, float, float],
              depth: float) -> tuple[float, float]:
    """(deg per px RMS with the translation free, % of ``depth`` per px RMS with the rotation
    free) of a camera seeing ``pts_cam`` (N, 3) with pinhole ``intrinsics`` (fx, fy, cx, cy):
    the weakest direction of the linearised projection after the other block compensates."""
    from pgt_check.geometry.reprojection import residuals_jac
    from pgt_check.verdict.calibration import camera_matrix

    x = np.asarray(pts_cam, np.float64).reshape(-1, 3)
    k = camera_matrix(intrinsics)
    # px per left update (dw, dt) of the camera at these points: x -> exp(dw) x + dt
    _, jac = residuals_jac(k, x, np.zeros((len(x), 2)), np.eye(3), np.zeros(3))
    j_rot = jac[:, :, :3].reshape(-1, 3) * (np.pi / 180.0)  # px per deg
    j_t = jac[:, :, 3:].reshape(-1, 3) * (depth / 100.0)  # px per 1 % of the depth
    n = len(x)

    def weakest(a: np.ndarray, b: np.ndarray) -> float:
        s = (a.T @ a - a.T @ b @ np.linalg.solve(b.T @ b, b.T @ a)) / n
        return float(1.0 / np.sqrt(max(np.linalg.eigvalsh(s)[0], 1e-30)))

    return weakest(j_rot, j_t), weakest(j_t, j_rot)


def scene(name: str, frames: int) -> dict:
    traj, mesh, cfgd = scenes_loso.load_scene(name, frames)
    _, ms, _ = measure(traj, mesh, cfgd, f"{scenes_loso._prefix(name)}-given")
    depth = scene_depth(ms)
    rot, tr = [], []
    for m in ms:
        ev = m.evidence
        if ev is None or m.intrinsics is None or len(ev.pts_cam) < 12:
            continue
        r, t = trade_off(np.asarray(ev.pts_cam), m.intrinsics, depth)
        rot.append(r)
        tr.append(t)
    return {"scene": name + (" (colourless)" if scenes_loso.SHADING else ""),
            "frames": len(rot), "width": ms[0].width if ms else 0,
            "deg_per_px": [float(np.median(rot)), float(np.percentile(rot, 90))],
            "depth_pct_per_px": [float(np.median(tr)), float(np.percentile(tr, 90))]}


def main() -> int:
    p = argparse.ArgumentParser()
    p.add_argument("--scene", action="append", default=[], choices=scenes_loso.ALL_SCENES)
    p.add_argument("--frames", type=int, default=30)
    p.add_argument("--shaded", action="store_true",
                   help="also the colourless copies (their own cached measurements)")
    args = p.parse_args()
    shared_errors.REUSE_MEASUREMENTS = True  # what the evidence saw: any cached measurement
    doc = json.loads(JSON.read_text()) if JSON.is_file() else {"rows": {}}
    for shading in (None, "shaded") if args.shaded else (None,):
        scenes_loso.SHADING = shading
        for s in args.scene or scenes_loso.ALL_SCENES:
            row = scene(s, args.frames)
            doc["rows"][row["scene"]] = row
            print(json.dumps(row), flush=True)
    doc.update(command=command_line(), machine=machine())
    JSON.write_text(json.dumps(doc, indent=1) + "\n")
    def med(v: list[float]) -> str:
        return f"{v[0]:.2f} (p90 {v[1]:.2f})"

    rows = [[r["scene"], r["frames"], r["width"], med(r["deg_per_px"]), med(r["depth_pct_per_px"])]
            for r in doc["rows"].values()]
    MD.write_text("\n".join([
        "# One photo's pose: the rotation/translation trade-off per scene", "",
        (__doc__ or "").split("\n\n    python")[0].split("\n", 1)[1].strip(), "",
        f"`{doc['command']}`; {doc['machine']}", "",
        md_table(["scene", "frames", "photo width (px)",
                  "deg per px RMS, translation free (median)",
                  "% of the depth per px RMS, rotation free (median)"], rows), ""]))
    print(MD.read_text())
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
