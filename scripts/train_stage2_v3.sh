#!/usr/bin/env bash
# Stage 2 v3 on the CPU: fine-tune improvement model v1 on what the pipeline now renders: the
# shipped generator run at 64 px (its trained size) and its Gaussians seen at 64 and 128 px,
# raw and refined (prosplat.refine, 300 steps against the inputs at the views' size). v2's
# recipe (replicate padding, alpha input, 48-px crops, flips, LPIPS weight 0.1); batches come
# from the four curated sets in turn. Resumable: finished curated sets are kept, and re-running
# continues the run in runs/s2v3/run.
#   scripts/train_stage2_v3.sh [STEPS]   (default 3000; INIT= another starting file,
#   LPIPS= the LPIPS weight (default 0.1), RUN= the run folder under runs/s2v3 (default run))
# Data: data/train128 (scripts/render_v2_data.sh train 2) and data/val128 (... eval), curated
# by scripts/curate_stage2_sets.sh.
set -euo pipefail
cd "$(dirname "$0")/.."
P=${PROSPLAT:-.venv/bin/prosplat}
OUT=runs/s2v3
scripts/curate_stage2_sets.sh $OUT
$P train improve --data $OUT/raw64.safetensors,$OUT/ref64.safetensors,$OUT/raw128.safetensors,$OUT/ref128.safetensors \
  --val $OUT/val_ref128.safetensors --out $OUT/${RUN:-run} \
  --init "${INIT:-prosplat/weights/improve_tiny.safetensors}" --padding replicate --alpha --crop 48 \
  --flip --steps "${1:-3000}" --batch 8 --lr 2e-4 --warmup 50 --lpips-weight ${LPIPS:-0.1} \
  --val-every 500 --save-every 100 --log-every 20
