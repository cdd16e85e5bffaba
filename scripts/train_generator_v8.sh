#!/usr/bin/env bash
# Generator v8: shipped v7 fine-tuned for STEPS more steps with v7's recipe (v5's losses, 64 and
# 128 px, windows of other shapes; scripts/train_generator_v7.sh) on the same 420 scenes of
# data/train128 with a new batch seed (2), saving a moving average of the weights (--ema):
# at this learning rate checkpoints 250 steps apart differ by more than a run gains.
#   FRAME_PROB (default 0.5) : share of the 128-px steps on windows of other shapes
#   EMA (default 0.998)      : decay of the weight average; 0 saves the raw weights
# ~1 s a step on one thread. Resumable: re-run to go on (the run folder keeps its state); a
# run started without EMA takes it up from where it resumes.
# EXTRA_ARGS: more `train generator` flags, after the recipe's (so they override it).
# SCENES / SUBSET pass through to train_generator_v6.sh (another set of data/train128's seeds),
# e.g. the first 3 render rounds: SCENES="10000-10179 $(. scripts/scene_subset.sh; hard_rounds 3)".
#   OUT=runs/gen_v8 [INIT=...] [SEED=2] [FRAME_PROB=0.5] [EMA=0.998] [SCENES=... SUBSET=...] \
#     scripts/train_generator_v8.sh [STEPS]
set -euo pipefail
cd "$(dirname "$0")/.."
. scripts/shipped_before.sh
# the default start is fetched from git history; an INIT the caller names must exist (train
# generator says so), never silently replaced by these weights
if [ -z "${INIT:-}" ]; then
  INIT=runs/generator_v7.safetensors
  shipped_before "$INIT" generator_tiny.safetensors fca9402  # generator v7
fi
GROW_ALEXNET=0 INIT="$INIT" OUT="${OUT:-runs/gen_v8}" SEED="${SEED:-2}" \
  EXTRA_ARGS="--frame-prob ${FRAME_PROB:-0.5} --ema ${EMA:-0.998} ${EXTRA_ARGS:-}" \
  exec scripts/train_generator_v6.sh "${1:-5000}"
