#!/usr/bin/env bash
# Stage 2 v4 on the CPU: the tiny improvement model trained FROM SCRATCH (not from v1) on what
# the pipeline renders: the shipped generator run at 64 px, its Gaussians seen at 64 and 128 px,
# raw and refined (prosplat.refine, 300 steps). v2's recipe otherwise (replicate padding, the
# render's alpha as an input, 48-px crops, flips, LPIPS weight 0.1), lr 5e-4, 8,000 steps,
# batches from the four curated sets in turn.
# Why from scratch: every model fine-tuned from v1 (v2, v3, v3b) kept v1's habit of painting
# green-and-yellow blobs where the render is blurry; v4 stamps no blobs (BENCHMARKS,
# "Stage 2 v4").
# The curated sets are v3's (scripts/curate_stage2_sets.sh, same options), so they are made
# once for both. Resumable: finished sets are kept, and re-running continues the run (raise
# STEPS to train on; the run folder keeps its optimizer state).
#   scripts/train_stage2_v4.sh [STEPS]   (default 8000; RUN= the run folder under runs/s2v4;
#   SETS= the curated sets' folder, default runs/s2v3)
# Data: data/train128 (scripts/render_v2_data.sh train N) and data/val128 (... eval).
set -euo pipefail
cd "$(dirname "$0")/.."
P=${PROSPLAT:-.venv/bin/prosplat}
SETS=${SETS:-runs/s2v3}
OUT=runs/s2v4
mkdir -p $OUT
scripts/curate_stage2_sets.sh $SETS
$P train improve --data $SETS/raw64.safetensors,$SETS/ref64.safetensors,$SETS/raw128.safetensors,$SETS/ref128.safetensors \
  --val $SETS/val_ref128.safetensors --out $OUT/${RUN:-run} --padding replicate --alpha --crop 48 \
  --flip --steps "${1:-8000}" --batch 8 --lr 5e-4 --warmup 100 --lpips-weight 0.1 \
  --val-every 1000 --save-every 100 --log-every 50
