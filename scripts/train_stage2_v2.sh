#!/usr/bin/env bash
# Stage 2 v2 on the CPU: fine-tune improvement model v1 (INIT) on renders of the shipped
# generator, with replicate padding, the render's alpha as an input and random crops + flips
# (v1's fixed pattern is tied to pixel positions). Resumable: re-running continues the run in
# runs/s2v2/rep01. The v2 candidate then got working_size 256 (prosplat/weights/README.md).
#   scripts/train_stage2_v2.sh [STEPS]   (default 1500; INIT= another v1 file)
# Data: data/train128 (scripts/render_v2_data.sh train 1) and data/val128 (... eval).
set -euo pipefail
cd "$(dirname "$0")/.."
P=${PROSPLAT:-.venv/bin/prosplat}
OUT=runs/s2v2
mkdir -p $OUT
[ -f $OUT/train.safetensors ] || $P train curate --data data/train128 --out $OUT/train.safetensors \
  --views 2,3,4,6 --size 64
[ -f $OUT/val.safetensors ] || $P train curate --data data/val128 --out $OUT/val.safetensors \
  --views 2,4 --size 64
$P train improve --data $OUT/train.safetensors --val $OUT/val.safetensors --out $OUT/rep01 \
  --init "${INIT:-prosplat/weights/improve_tiny.safetensors}" --padding replicate --alpha --crop 48 \
  --flip --steps "${1:-1500}" --batch 8 --lr 2e-4 --warmup 50 --lpips-weight 0.1 \
  --val-every 500 --save-every 100 --log-every 20
