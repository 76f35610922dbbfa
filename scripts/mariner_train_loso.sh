#!/usr/bin/env bash
# Leave-one-scene-out MaRINeR models (issue 37, item 2), one after the other, resumable.
# Usage: bash scripts/mariner_train_loso.sh [CACHE_DIR] [MINUTES_EACH] [SCENE ...]
# Needs the triple caches of scripts/mariner_train_all.sh in CACHE_DIR (run that first; it builds
# them). For each left-out SCENE (default: redkitchen bm_asclepius bm_mictlantecuhli
# bm_virgin_child) the same recipe as the all-scenes run is trained on the other scenes' caches
# into CACHE_DIR/run_lo_SCENE, from the matching-only base (a new gated model is the base), and
# resumed from its own last.pt when run again. The castle is in no cache: every model is a
# left-out model for it. Checkpoints to commit: CACHE_DIR/run_lo_SCENE/{best.pt,log.csv}.
set -euo pipefail
cd "$(dirname "$0")/.."
C=${1:-$HOME/.cache/pgt_check/mariner_all}
MIN=${2:-30}
shift $(( $# > 2 ? 2 : $# ))
SCENES=("$@")
[ ${#SCENES[@]} -gt 0 ] || SCENES=(redkitchen bm_asclepius bm_mictlantecuhli bm_virgin_child)
export OMP_NUM_THREADS=1
ALL=(redkitchen bm_asclepius bm_mictlantecuhli bm_virgin_child)
for s in "${SCENES[@]}"; do
  caches=()
  for o in "${ALL[@]}"; do
    [ "$o" = "$s" ] || caches+=("$C/tr_$o")
  done
  for c in "${caches[@]}"; do [ -d "$c" ] || { echo "missing triple cache $c" >&2; exit 1; }; done
  mkdir -p "$C/run_lo_$s"
  python -m mariner_core.train_frozen train --out "$C/run_lo_$s" \
    --caches "$(IFS=,; echo "${caches[*]}")" \
    --max-minutes "$MIN" --crop 64 --batch-size 16 --gated --colour-aug 0.5 --render-aug 0.3 \
    --threads 1 --val-every-minutes 25 --resume
done
