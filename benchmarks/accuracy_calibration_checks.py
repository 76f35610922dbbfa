"""What the calibration rig leaves on the disjoint 7-Scenes frames (500-640) is: two checks on a
work folder of ``benchmarks/accuracy_calibration.sh`` (reports/accuracy.md, "Calibration written
out").

* ``second-round``: the estimation frames checked again through their own rig; that second
  estimate composed with the first (rig x rig, focal x focal) and applied to frames 500-640.
* ``time-offset``: frames 500-640 with their poses moved along the trajectory by a fraction of
  the spacing to the next / previous evaluation frame (slerp; 0.1 = one frame of the 30 Hz
  stream), checked through the first rig.

    PGT_SHARED_DATA=... nice -n 10 python benchmarks/accuracy_calibration_checks.py WORK_DIR

Prints the registration / calibration effect left per case."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
from _common import shared_data
from scipy.spatial.transform import Rotation, Slerp

FRAMES = (500, 640)


def _check(traj: Path, sensors: Path, out: Path) -> str:
    """One ``pgt-check --preset fast`` run as accuracy_calibration.sh does it; its shared line."""
    data = shared_data() / "7scenes_redkitchen"
    subprocess.run(["pgt-check", str(traj), "--mesh", str(data / "mesh.ply"), "--sensors",
                    str(sensors), "--images", str(data), "--out", str(out), "--preset", "fast",
                    "--overwrite", "--registration-rounds", "0", "-q"],
                   capture_output=True, check=False)
    se = json.loads((out / "summary.json").read_text())["shared_errors"]
    reg, cal = se["registration"], next(iter(se["calibration"].values()))
    return (f"registration {reg['status']} {reg['effect_px']:.2f} px, calibration "
            f"{cal['status']} {cal['effect_px']:.2f} px")


def _rows(path: Path) -> tuple[str, list[list[str]]]:
    lines = path.read_text().splitlines()
    return lines[0], [[x.strip() for x in line.split(",")] for line in lines[1:] if line.strip()]


def _pose(row: list[str]) -> tuple[Rotation, np.ndarray]:
    qw, qx, qy, qz, *t = map(float, row[2:9])
    return Rotation.from_quat([qx, qy, qz, qw]), np.array(t)


def _write_rig_session(folder: Path, head: str, rows: list[list[str]], rig: np.ndarray,
                       sensors: list[str]) -> None:
    """A LaMAR rig session: ``rows`` posed as the rig ``rig_cam0`` holding camera cam0."""
    folder.mkdir(parents=True, exist_ok=True)
    x, y, z, w = Rotation.from_matrix(rig[:3, :3]).as_quat()
    (folder / "rigs.txt").write_text("# rig_id, sensor_id, qw, qx, qy, qz, tx, ty, tz\n"
                                     f"rig_cam0, cam0, {w}, {x}, {y}, {z}, "
                                     f"{rig[0, 3]}, {rig[1, 3]}, {rig[2, 3]}\n")
    (folder / "sensors.txt").write_text("# sensor_id, name, sensor_type, [sensor_params]+\n"
                                        + ", ".join(sensors) + "\n")
    (folder / "trajectories.txt").write_text(
        head + "\n" + "".join(", ".join([r[0], "rig_" + r[1], *r[2:]]) + "\n" for r in rows))
    (folder / "images.txt").write_text(
        (shared_data() / "7scenes_redkitchen" / "images.txt").read_text())


def _first_rig(w: Path) -> tuple[np.ndarray, list[str]]:
    _, rows = _rows(w / "est" / "calibrated" / "rigs.txt")
    r, t = _pose(rows[0])
    rig = np.eye(4)
    rig[:3, :3], rig[:3, 3] = r.as_matrix(), t
    _, sensors = _rows(w / "est" / "calibrated" / "sensors.txt")
    return rig, sensors[0]


def second_round(w: Path) -> str:
    rig1, sensors = _first_rig(w)
    est = w / "est" / "calibrated"
    _check(est / "trajectories.txt", est / "sensors.txt", w / "est2")
    c = next(iter(json.loads((w / "est2" / "summary.json").read_text())
                  ["shared_errors"]["calibration"].values()))
    true_from_checked = np.eye(4)
    true_from_checked[:3, :3] = np.asarray(c["rotation"])
    rig = rig1 @ np.linalg.inv(true_from_checked)
    f = repr(float(sensors[6]) * float(c["focal_scale"]))
    head, rows = _rows(w / "b" / "trajectories.txt")
    _write_rig_session(w / "rig2", head, rows, rig, [*sensors[:6], f, f, *sensors[8:]])
    return _check(w / "rig2" / "trajectories.txt", w / "rig2" / "sensors.txt", w / "rig2_out")


def time_offset(w: Path, fraction: float) -> str:
    rig, sensors = _first_rig(w)
    head, rows = _rows(shared_data() / "7scenes_redkitchen" / "trajectories.txt")
    moved = []
    for i, row in enumerate(rows):
        if not FRAMES[0] <= int(row[0]) <= FRAMES[1]:
            continue
        (r0, t0), (r1, t1) = _pose(row), _pose(rows[i + (1 if fraction > 0 else -1)])
        a = abs(fraction)
        x, y, z, qw = Slerp([0, 1], Rotation.concatenate([r0, r1]))([a])[0].as_quat()
        t = (1 - a) * t0 + a * t1
        moved.append([row[0], row[1], *(f"{v:.9f}" for v in (qw, x, y, z, *t))])
    folder = w / f"shift{fraction:+.1f}"
    _write_rig_session(folder, head, moved, rig, sensors)
    return _check(folder / "trajectories.txt", folder / "sensors.txt", folder / "out")


def main() -> None:
    w = Path(sys.argv[1])
    print("second round composed:", second_round(w), flush=True)
    for fraction in (-0.2, -0.1, 0.1, 0.2):
        print(f"poses moved {fraction:+.1f} of the spacing:", time_offset(w, fraction), flush=True)


if __name__ == "__main__":
    main()
