#!/usr/bin/env bash
# Stage 2 v5 on the CPU: the shipped v4 fine-tuned on what generator v2 renders (DESIGN.md:
# stage-2 weights follow the generator that made their training renders). The same curated
# sets as v4's (scripts/curate_stage2_sets.sh: raw and 300-step refined renders at 64 and
# 128 px, the generator at 64 px) made with generator v2 into runs/s2v5/sets, and v4's recipe
# (replicate padding, alpha input, 48-px crops, flips, LPIPS weight 0.1) at a lower rate.
# Fine-tuned from v4, not from v1: v4 stamps no blobs of its own, v1's descendants did.
# Resumable like every run here: finished sets are kept, and re-running continues the run.
#   scripts/train_stage2_v5.sh [STEPS]   (default 3000; GEN= the generator, default the shipped
#   one; INIT= the starting stage 2, default runs/s2v4/scratch8000.safetensors = v4)
set -euo pipefail
cd "$(dirname "$0")/.."
P=${PROSPLAT:-.venv/bin/prosplat}
SETS=runs/s2v5/sets
GEN=${GEN:-prosplat/weights/generator_tiny.safetensors} scripts/curate_stage2_sets.sh $SETS
$P train improve --data $SETS/raw64.safetensors,$SETS/ref64.safetensors,$SETS/raw128.safetensors,$SETS/ref128.safetensors \
  --val $SETS/val_ref128.safetensors --out runs/s2v5/run --init "${INIT:-runs/s2v4/scratch8000.safetensors}" \
  --padding replicate --alpha --crop 48 --flip --steps "${1:-3000}" --batch 8 --lr 2e-4 --warmup 100 \
  --lpips-weight 0.1 --val-every 500 --save-every 100 --log-every 50
