#!/usr/bin/env bash
# The curated stage-2 training sets that scripts/train_stage2_v3.sh and train_stage2_v4.sh both
# train on: what the pipeline renders, the shipped generator run at 64 px (its trained size) and
# its Gaussians seen at 64 and 128 px, raw and refined (prosplat.pipeline.refine, 300 steps):
#   raw64 (2/3/4/6 inputs), ref64, raw128, ref128 (2/4 inputs) from data/train128;
#   val_ref128 (4 inputs) and val_raw64 (2/4) from data/val128.
# Finished sets are kept, so re-running only makes what is missing (~25 min on 2 cores from
# nothing, two curations at a time).
#   scripts/curate_stage2_sets.sh [DIR [NAME...]]   (default runs/s2v3 and all six sets; NAMEs
#   pick some of them, e.g. raw64 raw128; GEN= another generator checkpoint; GEN_SIZE= the
#   largest size the generator runs at, default 64, e.g. 128 for one trained at 64 and 128 px
#   as the pipeline runs it; DATA= another training-scene folder than data/train128, e.g. the
#   subset a generator was trained on; SPLAT= the Gaussians drawn at that multiple of their
#   scales, `train curate --splat-scale`, default 1)
set -euo pipefail
cd "$(dirname "$0")/.."
P=${PROSPLAT:-.venv/bin/prosplat}
# two curations at once, one thread each: with torch's default threads each, a third process on
# this 2-core machine made them 5-10x slower
export OMP_NUM_THREADS=${OMP_NUM_THREADS:-1}
DIR=${1:-runs/s2v3}
DATA=${DATA:-data/train128}
WANT=" ${*:2} "
mkdir -p "$DIR"
curate() {  # NAME DATA VIEWS SIZE REFINE_STEPS
  [ "$WANT" = "  " ] || [[ "$WANT" == *" $1 "* ]] || return 0
  [ -f "$DIR/$1.safetensors" ] || $P train curate --data $2 --out "$DIR/$1.safetensors" \
    --views $3 --size $4 --generator-size ${GEN_SIZE:-64} --refine-steps $5 ${GEN:+--generator "$GEN"} \
    ${SPLAT:+--splat-scale "$SPLAT"}
}
curate raw64 $DATA 2,3,4,6 64 0 &
curate ref128 $DATA 2,4 128 300
wait
curate raw128 $DATA 2,4 128 0 &
curate ref64 $DATA 2,4 64 300
wait
curate val_ref128 data/val128 4 128 300 &
curate val_raw64 data/val128 2,4 64 0
wait
