#!/usr/bin/env bash
# Train the gated cpu-frozen MaRINeR on every shared scene's training pool (issue 37), resumable.
# Usage: bash scripts/mariner_train_all.sh [CACHE_DIR] [MINUTES]
# Frame caches and triple caches go to CACHE_DIR (default ~/.cache/pgt_check/mariner_all; a few
# GB, never in the repo); the run to CACHE_DIR/run_all: resumed from its own last.pt, or, when
# the run folder is new, started from the committed reports/mariner_runs/all_scenes/best.pt
# (weights only: the optimiser state and the learning-rate schedule start afresh; the optimiser
# state was not committed, it would double the file).
# Held out: every bm_* frame with timestamp % 10 == 0 (their evaluation split) and the whole of
# 7scenes_redkitchen/ and sceaux_castle/ (never trained on). See reports/mariner_training.md.
set -euo pipefail
cd "$(dirname "$0")/.."
D=${PGT_SHARED_DATA:-$(cd .. && pwd)/shared/data}
C=${1:-$HOME/.cache/pgt_check/mariner_all}
MIN=${2:-80}
mkdir -p "$C"
export OMP_NUM_THREADS=1
TD="python -m pgt_check.enhance.training_data"
# 7-Scenes training pool: every 2nd frame (400 of 800) keeps the cache affordable on 2 cores
awk 'NR==1 || (NR%2==0)' "$D/7scenes_redkitchen_train/trajectories.txt" > "$C/rk_train_half.txt"
[ -f "$C/fc_redkitchen_train/index.json" ] || $TD --trajectory "$C/rk_train_half.txt" \
  --images "$D/7scenes_redkitchen_train/images.txt" --sensors "$D/7scenes_redkitchen_train/sensors.txt" \
  --mesh "$D/7scenes_redkitchen/mesh.ply" --out "$C/fc_redkitchen_train"
for s in bm_asclepius bm_mictlantecuhli bm_virgin_child; do
  [ -f "$C/fc_$s/index.json" ] || $TD --trajectory "$D/$s/trajectories.txt" \
    --sensors "$D/$s/sensors.txt" --mesh "$D/$s/mesh.ply" --out "$C/fc_$s"
done
[ -f "$C/fc_redkitchen_eval/index.json" ] || $TD --trajectory "$D/7scenes_redkitchen/trajectories.txt" \
  --sensors "$D/7scenes_redkitchen/sensors.txt" --mesh "$D/7scenes_redkitchen/mesh.ply" --out "$C/fc_redkitchen_eval"
[ -f "$C/fc_sceaux_castle/index.json" ] || $TD --trajectory "$D/sceaux_castle/trajectories.txt" \
  --sensors "$D/sceaux_castle/sensors.txt" --mesh "$D/sceaux_castle/mesh.ply" --out "$C/fc_sceaux_castle"
# triples (resumable): bm references 1-8 capture positions away, 7-Scenes 5-60 frames (30 Hz);
# 15 % of the references are the frame's own photo (Ref = target)
CACHE="python -m mariner_core.train_frozen cache --self-share 0.15"
for s in bm_asclepius bm_mictlantecuhli bm_virgin_child; do
  $CACHE --data "$C/fc_$s" --out "$C/tr_$s" --pairs 2 --min-gap 1 --max-gap 8 --exclude-mod 10 \
    --val-offset 4 --val-every 1
done
$CACHE --data "$C/fc_redkitchen_train" --out "$C/tr_redkitchen" --pairs 1 --min-gap 5 --max-gap 60 \
  --val-offset 20 --val-every 4
mkdir -p "$C/run_all"
INIT=()
if [ ! -f "$C/run_all/last.pt" ] && [ -f reports/mariner_runs/all_scenes/best.pt ]; then
  INIT=(--init reports/mariner_runs/all_scenes/best.pt)
fi
python -m mariner_core.train_frozen train --out "$C/run_all" "${INIT[@]}" \
  --caches "$C/tr_redkitchen,$C/tr_bm_asclepius,$C/tr_bm_mictlantecuhli,$C/tr_bm_virgin_child" \
  --max-minutes "$MIN" --crop 64 --batch-size 16 --gated --colour-aug 0.5 --render-aug 0.3 \
  --threads 1 --val-every-minutes 25 --resume
