#!/usr/bin/env bash
# Stage 2 v7 (candidate): v6 fine-tuned on generator v3's renders (stage-2 weights follow the
# generator that made their training renders: v6 saw v2's). v6's recipe otherwise (the warp,
# replicate padding, alpha, 48-px crops, flips, LPIPS weight 0.1), raw renders at 64 and 128
# px curated with the warped references.
# Resumable: finished sets are kept, and re-running continues the training run.
#   scripts/train_stage2_v7.sh [STEPS]   (default 3000; GEN= the generator, default v3 taken
#   from git history; INIT= the starting stage 2, default v6 taken from git history; OUT=)
set -euo pipefail
cd "$(dirname "$0")/.."
P=${PROSPLAT:-.venv/bin/prosplat}
GEN=${GEN:-runs/generator_v3.safetensors}
INIT=${INIT:-runs/s2v7/v6.safetensors}
. scripts/shipped_before.sh
shipped_before "$GEN" generator_tiny.safetensors 3fee24e  # generator v3
shipped_before "$INIT" improve_tiny.safetensors 3fee24e   # stage 2 v6
SETS=${SETS:-runs/s2v7/sets}
OUT=${OUT:-runs/s2v7/run}
GEN="$GEN" scripts/curate_stage2_sets.sh $SETS raw64 raw128 val_raw64
$P train improve --data $SETS/raw64.safetensors,$SETS/raw128.safetensors \
  --val $SETS/val_raw64.safetensors --out "$OUT" --init "$INIT" --warp \
  --padding replicate --alpha --crop 48 --flip --steps "${1:-3000}" --batch 8 --lr 2e-4 --warmup 100 \
  --lpips-weight 0.1 --val-every 500 --save-every 100 --log-every 50
