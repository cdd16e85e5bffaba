#!/usr/bin/env bash
# Stage 2 v4 on the CPU: the tiny improvement model trained FROM SCRATCH (not from v1) on what
# the pipeline renders: the shipped generator run at 64 px, its Gaussians seen at 64 and 128 px,
# raw and refined (prosplat.refine, 300 steps). v2's recipe otherwise (replicate padding, the
# render's alpha as an input, 48-px crops, flips, LPIPS weight 0.1), lr 5e-4, 8,000 steps,
# batches from the four curated sets in turn.
# Why from scratch: every model fine-tuned from v1 (v2, v3, v3b) kept v1's habit of painting
# green-and-yellow blobs where the render is blurry; v4 stamps no blobs (BENCHMARKS,
# "Stage 2 v4").
# Resumable: finished curated sets are kept, and re-running continues the run (raise STEPS to
# train on; the run folder keeps its optimizer state).
#   scripts/train_stage2_v4.sh [STEPS]   (default 8000; RUN= the run folder under runs/s2v4)
# Data: data/train128 (scripts/render_v2_data.sh train N) and data/val128 (... eval).
set -euo pipefail
cd "$(dirname "$0")/.."
P=${PROSPLAT:-.venv/bin/prosplat}
OUT=runs/s2v4
mkdir -p $OUT
curate() {  # NAME DATA VIEWS SIZE REFINE_STEPS
  [ -f $OUT/$1.safetensors ] || $P train curate --data $2 --out $OUT/$1.safetensors --views $3 \
    --size $4 --generator-size 64 --refine-steps $5
}
curate raw64 data/train128 2,3,4,6 64 0 &
curate ref128 data/train128 2,4 128 300
wait
curate raw128 data/train128 2,4 128 0 &
curate ref64 data/train128 2,4 64 300
wait
curate val_ref128 data/val128 4 128 300
$P train improve --data $OUT/raw64.safetensors,$OUT/ref64.safetensors,$OUT/raw128.safetensors,$OUT/ref128.safetensors \
  --val $OUT/val_ref128.safetensors --out $OUT/${RUN:-run} --padding replicate --alpha --crop 48 \
  --flip --steps "${1:-8000}" --batch 8 --lr 5e-4 --warmup 100 --lpips-weight 0.1 \
  --val-every 1000 --save-every 100 --log-every 50
