#!/usr/bin/env bash
# Stage 2 v5b on the CPU (trained, not shipped: +0.1 dB over v5, BENCHMARKS "Stage 2 v6"): v5
# fine-tuned on renders that all come from generator v2 (v5's refined sets were still made by
# v1; DESIGN.md: stage-2 weights follow the generator that made their training renders). Same recipe as v5 (replicate padding, alpha input, 48-px crops,
# flips, LPIPS weight 0.1, lr 2e-4).
# Data (runs/s2v5/sets, scripts/curate_stage2_sets.sh): generator v2's raw renders at 64 and
# 128 px and its Gaussians refined for 300 steps and rendered at 64 and 128 px, from
# data/train128; validation val_ref128 (data/val128, 4 inputs).
# Resumable: finished sets are kept, and re-running continues the training run.
#   scripts/train_stage2_v5b.sh [STEPS]   (default 3000; GEN= the generator, default v2 taken
#   from git history; INIT= the starting stage 2, default v5 taken from git history; OUT=)
set -euo pipefail
cd "$(dirname "$0")/.."
P=${PROSPLAT:-.venv/bin/prosplat}
GEN=${GEN:-runs/generator_v2.safetensors}
INIT=${INIT:-runs/s2v6/v5.safetensors}
. scripts/shipped_before.sh
shipped_before "$GEN" generator_tiny.safetensors 17c555c  # generator v2
shipped_before "$INIT" improve_tiny.safetensors 17c555c   # stage 2 v5
SETS=${SETS:-runs/s2v5/sets}
OUT=${OUT:-runs/s2v6/run}  # (the run's folder name predates the rename)
GEN="$GEN" scripts/curate_stage2_sets.sh $SETS raw64 raw128 ref128 ref64 val_ref128
$P train improve --data $SETS/raw64.safetensors,$SETS/ref64.safetensors,$SETS/raw128.safetensors,$SETS/ref128.safetensors \
  --val $SETS/val_ref128.safetensors --out "$OUT" --init "$INIT" \
  --padding replicate --alpha --crop 48 --flip --steps "${1:-3000}" --batch 8 --lr 2e-4 --warmup 100 \
  --lpips-weight 0.1 --val-every 500 --save-every 100 --log-every 50
