#!/usr/bin/env bash
# Stage 2 v6 (shipped): the warped reference (ImproveConfig.warp_input). v5 upgraded by
# load_improver(warp_input=True) (the new input starts at zero weights, so step 0 is v5) and
# fine-tuned on generator v2's raw renders at 64 and 128 px, curated with
# the reference warped through the rendered depth (prosplat.improve.warp). Same recipe as
# v5/v6 otherwise (replicate padding, alpha, 48-px crops, flips, LPIPS weight 0.1).
# Resumable: finished sets are kept, and re-running continues the training run.
# The control (the same run without --warp, runs/s2w/control) gained nothing: the warp is it.
#   scripts/train_stage2_v6.sh [STEPS]   (default 3000; GEN= the generator, default v2 taken
#   from git history; INIT= the starting stage 2, default v5 taken from git history; OUT=)
set -euo pipefail
cd "$(dirname "$0")/.."
P=${PROSPLAT:-.venv/bin/prosplat}
GEN=${GEN:-runs/generator_v2.safetensors}
INIT=${INIT:-runs/s2w/v5.safetensors}
. scripts/shipped_before.sh
shipped_before "$GEN" generator_tiny.safetensors 17c555c  # generator v2
shipped_before "$INIT" improve_tiny.safetensors 17c555c   # stage 2 v5
SETS=${SETS:-runs/s2w/sets}
OUT=${OUT:-runs/s2w/run}
GEN="$GEN" scripts/curate_stage2_sets.sh $SETS raw64 raw128 val_raw64
$P train improve --data $SETS/raw64.safetensors,$SETS/raw128.safetensors \
  --val $SETS/val_raw64.safetensors --out "$OUT" --init "$INIT" --warp \
  --padding replicate --alpha --crop 48 --flip --steps "${1:-3000}" --batch 8 --lr 2e-4 --warmup 100 \
  --lpips-weight 0.1 --val-every 500 --save-every 100 --log-every 50
