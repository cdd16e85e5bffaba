#!/usr/bin/env bash
# Stage 2 v9 (candidate): v7 fine-tuned on generator v5's renders, v8's recipe otherwise
# (scripts/train_stage2_v8.sh: the warp, replicate padding, alpha, 48-px crops, flips, LPIPS
# weight 0.1, 3,000 steps). v5 runs at 128 px where v4 ran at 64 (it was trained at both), so
# its 128-px renders are curated with the generator at 128 px, as the pipeline runs it; the
# scenes are the 246 of data/gen_v4b (v5 was trained on them and 246 more).
# Resumable: finished sets are kept, and re-running continues the training run.
#   scripts/train_stage2_v9.sh [STEPS [TRAIN ARGS...]]   (default 3000; the further arguments
#   go to `prosplat train improve`, as scripts/train_stage2_v10.sh does; GEN= the generator, default
#   runs/generator_v5.safetensors; INIT= the starting stage 2, default v7 from git history;
#   OUT=)
set -euo pipefail
cd "$(dirname "$0")/.."
P=${PROSPLAT:-.venv/bin/prosplat}
GEN=${GEN:-runs/generator_v5.safetensors}
INIT=${INIT:-runs/s2v8/v7.safetensors}
. scripts/shipped_before.sh
shipped_before "$INIT" improve_tiny.safetensors 6937825  # stage 2 v7
[ -f "$GEN" ] && [ -d data/gen_v4b ] ||
  { echo "no $GEN or data/gen_v4b: run scripts/train_generator_v5.sh and v4.sh first" >&2; exit 1; }
SETS=${SETS:-runs/s2v9/sets}
OUT=${OUT:-runs/s2v9/run}
# two curations at once (one thread each), then the training on both threads
export GEN GEN_SIZE=128
DATA=data/gen_v4b scripts/curate_stage2_sets.sh $SETS raw64 val_raw64 &
DATA=data/gen_v4b scripts/curate_stage2_sets.sh $SETS raw128
wait
OMP_NUM_THREADS=${OMP_NUM_THREADS:-2} $P train improve \
  --data $SETS/raw64.safetensors,$SETS/raw128.safetensors \
  --val $SETS/val_raw64.safetensors --out "$OUT" --init "$INIT" --warp \
  --padding replicate --alpha --crop 48 --flip --steps "${1:-3000}" --batch 8 --lr 2e-4 --warmup 100 \
  --lpips-weight 0.1 --val-every 500 --save-every 100 --log-every 50 "${@:2}"
