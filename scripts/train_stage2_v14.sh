#!/usr/bin/env bash
# Stage 2 v14 candidate: v13's recipe with refined renders in the fine-tune (issue 18, "stage 2
# on refined renders"). v10 + 2,000 steps at LPIPS weight 1.0 with the sub-pixel shift term on
# generator v5's raw renders (raw64 / raw128 / raw256, as v13) *and* on the same scenes
# refined for 100 steps (ref64: 2 and 4 inputs, ref128: 4 inputs; what `--refine-steps 100`
# and the add-on's 3-s default render), then blended back with v10 at the fine-tune's share
# WEIGHT (default 0.3, as v13). Why: stage 2 had only seen raw renders, and refine + enhance
# gains only +0.39 / +0.25 dB over enhance alone at 64 / 128 px (issue 18 asks for +1 dB).
# Measured, not shipped (BENCHMARKS "Stage 2 on refined renders"): v13 within 0.02 dB after
# refinement, so the gap is not stage 2's.
#   1. scripts/train_stage2_v13.sh's data and raw sets (SETS13, default runs/s2v13/sets);
#   2. ref64 / ref128 curated here (~11 / ~26 min on one thread, two at once);
#   3. the fine-tune: scripts/train_stage2_v12.sh with LPIPS=1.0 and the refined sets added
#      (~12 min on one thread), and the blend, written to OUT/improve_v14.safetensors.
# Resumable: curated sets and the training run are kept.
#   scripts/train_stage2_v14.sh [STEPS]   (OUT= the run folder, default runs/s2v14)
set -euo pipefail
cd "$(dirname "$0")/.."
P=${PROSPLAT:-.venv/bin/prosplat}
OUT=${OUT:-runs/s2v14}
SETS13=${SETS13:-runs/s2v13/sets}
. scripts/shipped_before.sh
shipped_before "$OUT/v10.safetensors" improve_tiny.safetensors 028c321  # stage 2 v10
for s in raw64 raw128 raw256; do
  [ -f "$SETS13/$s.safetensors" ] || { echo "no $SETS13/$s.safetensors: run scripts/train_stage2_v13.sh first" >&2; exit 1; }
done
mkdir -p "$OUT/sets"
export OMP_NUM_THREADS=${OMP_NUM_THREADS:-1}
ref() {  # NAME VIEWS SIZE
  [ -f "$OUT/sets/$1.safetensors" ] || $P train curate --data data/train128 \
    --out "$OUT/sets/$1.safetensors" --views "$2" --size "$3" --generator-size 128 --refine-steps 100
}
ref ref64 2,4 64 &
pid=$!
ref ref128 4 128
wait $pid  # a failed curation stops the script (set -e)
EXTRA_SETS="$OUT/sets/ref64.safetensors,$OUT/sets/ref128.safetensors" LPIPS=1.0 \
  INIT="$OUT/v10.safetensors" SETS="$SETS13" OUT="$OUT/lp1r" scripts/train_stage2_v12.sh "${1:-2000}"
[ -f "$OUT/improve_v14.safetensors" ] || $P train blend "$OUT/v10.safetensors" \
  "$OUT/lp1r/improve.safetensors" --weight "${WEIGHT:-0.3}" --out "$OUT/improve_v14.safetensors"
