"""Class 3: resume is keyed on content: a pose edited in place, a replaced photo or a changed
mesh is measured again, never reused from the store."""

from __future__ import annotations

import json
import shutil


def _records(out):
    return [json.loads(line) for line in (out / "records.jsonl").read_text().splitlines()]


def test_pose_edited_in_place_is_measured_again(scene, cli, base_args, tmp_path, case):
    out = tmp_path / "out"
    rc, _, _ = cli(*base_args())
    assert rc == 0 and len(_records(out)) == 2
    traj = scene / "trajectories.txt"
    lines = traj.read_text().splitlines()
    parts = lines[1].split(",")
    parts[6] = f" {float(parts[6]) + 0.15:.9f}"  # frame 0's camera centre moves 15 cm in x
    lines[1] = ",".join(parts)
    traj.write_text("\n".join(lines) + "\n")
    rc, stdout, _ = cli(*base_args())
    recs = _records(out)
    again = [r["frame_id"] for r in recs[2:]]
    case("pose edited in place, rerun into the same --out", "frame re-measured, 1 (FAIL)",
         f"{rc}: re-measured {again} (frame 1 uses frame 0 as reference); "
         f"{stdout.splitlines()[0][10:70]}")
    assert recs[0]["frame_id"] in again  # the edited frame (its dependants may follow)
    assert rc == 1 and "1 FAIL" in stdout


def test_replaced_photo_is_measured_again(scene, cli, base_args, tmp_path, case):
    out = tmp_path / "out"
    assert cli(*base_args())[0] == 0
    shutil.copy(scene / "images" / "frame-000005.jpg", scene / "images" / "frame-000001.jpg")
    rc, _, _ = cli(*base_args())
    recs = _records(out)
    case("photo replaced by another photo", "frame re-measured",
         f"{rc}: re-measured {[r['frame_id'] for r in recs[2:]]}")
    assert recs[1]["frame_id"] in [r["frame_id"] for r in recs[2:]]
    # unchanged inputs: nothing is measured again
    assert cli(*base_args())[0] in (0, 1) and len(_records(out)) == len(recs)


def test_changed_mesh_is_refused_without_resume(scene, cli, base_args, tmp_path, case):
    assert cli(*base_args())[0] == 0
    with open(scene / "mesh.glb", "ab") as f:
        f.write(b"\0" * 4)  # same mesh to the loader, other bytes: a changed input
    rc, _, err = cli(*base_args())
    last = err.strip().splitlines()[-1]
    case("mesh content changed, rerun into the same --out", "2, names inputs.mesh",
         f"{rc}: {last[:140]}")
    assert rc == 2 and "inputs.mesh" in last
    rc, _, _ = cli(*base_args("--resume"))
    assert rc == 0 and len(_records(tmp_path / "out")) == 4  # both frames measured again
