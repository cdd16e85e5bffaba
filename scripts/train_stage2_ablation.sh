#!/usr/bin/env bash
# Issue 13's reference-injection ablation: from the same start (stage 2 v5) on the same data
# (generator v2's raw renders at 64 and 128 px with the warped references, runs/s2w/sets) and
# v6's recipe (3,000 steps, lr 2e-4, LPIPS weight 0.1, 48-px crops, flips, alpha, replicate
# padding), one run per row; only the reference switches differ:
#   none       no reference at all (--no-reference: v5's DWEA weights are left out)
#   plain      DWEA without its epipolar weighting (--no-epipolar: plain cross-attention)
#   dwea       DWEA (the paper's design; = runs/s2w/control, made by train_stage2_v6.sh's control)
#   warp       the warped reference alone (--no-reference --warp)
#   dwea_warp  DWEA + the warp (= shipped v6, runs/s2w/run)
# Runs go to runs/s2abl/ROW (resumable: re-running continues a run, a finished one is kept).
#   scripts/train_stage2_ablation.sh ROW...   (e.g. none warp; STEPS= to shorten)
# Then: prosplat eval ladder --rows enhanced --compare-improve none=runs/s2abl/none/... (see
# BENCHMARKS "Stage 2 ablation: how the reference is injected").
set -euo pipefail
cd "$(dirname "$0")/.."
P=${PROSPLAT:-.venv/bin/prosplat}
INIT=${INIT:-runs/s2w/v5.safetensors}
. scripts/shipped_before.sh
shipped_before "$INIT" improve_tiny.safetensors 17c555c  # stage 2 v5
SETS=${SETS:-runs/s2w/sets}
GEN=${GEN:-runs/generator_v2.safetensors}
shipped_before "$GEN" generator_tiny.safetensors 17c555c  # generator v2 (curates the sets)
GEN="$GEN" scripts/curate_stage2_sets.sh $SETS raw64 raw128 val_raw64
for row in "$@"; do
  case $row in
    none) flags="--no-reference" ;;
    plain) flags="--no-epipolar" ;;
    dwea) flags="" ;;
    warp) flags="--no-reference --warp" ;;
    dwea_warp) flags="--warp" ;;
    *) echo "unknown row $row (none plain dwea warp dwea_warp)" >&2; exit 2 ;;
  esac
  $P train improve --data $SETS/raw64.safetensors,$SETS/raw128.safetensors \
    --val $SETS/val_raw64.safetensors --out runs/s2abl/$row --init "$INIT" $flags \
    --padding replicate --alpha --crop 48 --flip --steps "${STEPS:-3000}" --batch 8 --lr 2e-4 \
    --warmup 100 --lpips-weight 0.1 --val-every 500 --save-every 100 --log-every 50
done
