#!/usr/bin/env bash
# Stage 2 v13: v10 fine-tuned with LPIPS weight 1.0 (and the sub-pixel shift term) on the
# renders of 288 training scenes, then blended back with v10: 0.7 x v10 + 0.3 x the fine-tune,
# weight by weight (`prosplat train blend`). The fine-tune alone is sharper (LPIPS 0.171 at
# 64 px) but flickers 1.32x the raw renders; the blend keeps flicker under issue 13's 1.2x
# (1.195x) with LPIPS 0.177 / 0.288 at 64 / 128 px against v10's 0.182 / 0.292
# (BENCHMARKS "Stage 2 v13").
#   1. data/train128: 4 rounds of scripts/render_v2_data.sh train (288 scenes: seeds
#      10000-10239 and the hard scenes 20000-20507; ~75 min on one thread);
#   2. data/train256: 33 scenes at 256 px (seeds 10000-10032; scripts/train_stage2_v11.sh);
#   3. scripts/train_stage2_v12.sh 2000 with LPIPS=1.0: curates raw64 / raw128 / raw256 with
#      generator v5 and fine-tunes v10 (from git history) for 2,000 steps (~10 min on one
#      thread);
#   4. the blend, written to OUT/improve_v13.safetensors.
# Resumable: rendered scenes, curated sets and the training run are kept.
#   scripts/train_stage2_v13.sh   (OUT= the run folder, default runs/s2v13; WEIGHT= the
#   fine-tune's share of the blend, default 0.3)
set -euo pipefail
cd "$(dirname "$0")/.."
P=${PROSPLAT:-.venv/bin/prosplat}
OUT=${OUT:-runs/s2v13}
. scripts/shipped_before.sh
shipped_before "$OUT/v10.safetensors" improve_tiny.safetensors 028c321  # stage 2 v10
WORKERS=1 scripts/render_v2_data.sh train 4
$P scenes render --seed 10000 --count 33 --out data/train256 --size 256 --inputs 4 \
  --targets 8 --samples 8 --denoise --workers 1  # skips finished scenes
LPIPS=1.0 INIT="$OUT/v10.safetensors" SETS="$OUT/sets" OUT="$OUT/lp1" \
  scripts/train_stage2_v12.sh 2000
[ -f "$OUT/improve_v13.safetensors" ] || $P train blend "$OUT/v10.safetensors" \
  "$OUT/lp1/improve.safetensors" --weight "${WEIGHT:-0.3}" --out "$OUT/improve_v13.safetensors"
