#!/usr/bin/env bash
# #27 calibration written out, checked on 7-Scenes: estimate the calibration on one set of frames
# (every 30th frame, 500-640 left out), write calibrated_sensors.txt, and re-run the disjoint
# frames 500-640 with it; compare with the given sensors and with the poses moved to the RGB
# camera by the extrinsic published with the visloc pseudo-GT (trajectories_dslam_rgb.txt); then
# the exact form (the estimate as a rig, out/calibrated/) on the same frames, and the disjoint
# frames' own rig applied to themselves (in sample: what is left when the estimate fits them).
# Prints the registration / calibration effect left on the disjoint frames (reports/accuracy.md).
#
#   [EXTRA=--calibration-translation] [STEP=10] [EST='awk condition'] \
#     nice -n 10 bash benchmarks/accuracy_calibration.sh [WORK_DIR]
# (STEP: the estimation frames are those whose id is a multiple of it; 30 by default. EST: an
# awk condition on the frame id $1 that chooses them instead, e.g. the neighbouring segments
# EST='($1>=400 && $1<=490) || ($1>=650 && $1<=740)')
set -euo pipefail
D=${PGT_SHARED_DATA:-$(cd "$(dirname "$0")/../.." && pwd)/shared/data}/7scenes_redkitchen
W=${1:-/tmp/pgt-check-accuracy-calibration}
mkdir -p "$W/a" "$W/b"
head -1 "$D/trajectories.txt" > "$W/a/trajectories.txt"
awk -F, -v s="${STEP:-30}" "NR>1 && (${EST:-(\$1%s==0)}) && !(\$1>=500 && \$1<=640)" \
  "$D/trajectories.txt" >> "$W/a/trajectories.txt"
for t in trajectories trajectories_dslam_rgb; do
  head -1 "$D/$t.txt" > "$W/b/$t.txt"
  grep -E "^(5[0-9]0|6[0-4]0)," "$D/$t.txt" >> "$W/b/$t.txt"
done
cp "$D/images.txt" "$D/sensors.txt" "$W/a/"
cp "$D/images.txt" "$D/sensors.txt" "$W/b/"
run() {  # trajectory sensors out
  pgt-check "$1" --mesh "$D/mesh.ply" --sensors "$2" --images "$D" --out "$3" --preset fast \
    --overwrite --registration-rounds 0 ${EXTRA:-} -q > "$3.log" 2>&1 || true
}
run "$W/a/trajectories.txt" "$W/a/sensors.txt" "$W/est"
cp "$W/est/calibrated_sensors.txt" "$W/b/calibrated_sensors.txt"
run "$W/b/trajectories.txt" "$W/b/sensors.txt" "$W/given"
run "$W/b/trajectories.txt" "$W/b/calibrated_sensors.txt" "$W/calibrated"
run "$W/b/trajectories_dslam_rgb.txt" "$W/b/sensors.txt" "$W/published_extrinsic"
# the exact form (out/calibrated/: the estimate as a LaMAR rig): the estimation run's rig and
# sensors with the disjoint frames' poses as the rig's
mkdir -p "$W/rig"
cp "$W/est/calibrated/rigs.txt" "$W/est/calibrated/sensors.txt" "$D/images.txt" "$W/rig/"
head -1 "$W/b/trajectories.txt" > "$W/rig/trajectories.txt"
tail -n +2 "$W/b/trajectories.txt" | sed -E 's/^([^,]*), *([^,]*),/\1, rig_\2,/' >> "$W/rig/trajectories.txt"
run "$W/rig/trajectories.txt" "$W/rig/sensors.txt" "$W/calibrated_rig"
# the floor: the disjoint frames' own estimate applied to themselves (in sample)
mkdir -p "$W/ins"
cp "$W/given/calibrated/rigs.txt" "$W/given/calibrated/sensors.txt" \
  "$W/given/calibrated/trajectories.txt" "$D/images.txt" "$W/ins/"
run "$W/ins/trajectories.txt" "$W/ins/sensors.txt" "$W/in_sample_rig"
python3 - "$W" <<'PY'
import json, sys
w = sys.argv[1]
for case in ("est", "given", "calibrated", "published_extrinsic", "calibrated_rig",
             "in_sample_rig"):
    s = json.load(open(f"{w}/{case}/summary.json"))
    se = s["shared_errors"]
    reg = se["registration"]
    cal = next(iter(se["calibration"].values()))
    print(f"{case}: {s['n_frames']} frames; registration {reg['status']} "
          f"{reg['effect_px']:.2f} px {reg['effect_px_ci']} ({reg['angle_deg']:.3f} deg); "
          f"calibration {cal['status']} {cal['effect_px']:.2f} px {cal['effect_px_ci']} "
          f"({cal['rotation_deg']:.3f} deg); shared threshold {se['threshold_px']:.2f} px")
PY
cat "$W/est/calibrated_sensors.txt"
