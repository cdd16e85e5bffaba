#!/usr/bin/env bash
# Generator v14 candidates: v12 grown by a module that matches the input images themselves,
# entering through zero weights so step 0 is v12 exactly, then v12's recipe (v8's with the
# input cameras' render term at 2):
#   v14a (default): --grow-image-matching 5, the images' ZNCC plane sweep as a depth-head
#        input (prosplat/generator/image_cost.py);
#   v14b: GROW="--grow-band 9" OUT=runs/gen_v14b SEED=10, a learned depth sweep after the
#        depth refiner (prosplat/generator/band.py).
#   scripts/train_generator_v14.sh [STEPS]      (OUT, SEED, GROW, EXTRA_ARGS override)
# Resumable: the same command continues from OUT's last checkpoint.
set -euo pipefail
cd "$(dirname "$0")/.."
. scripts/shipped_before.sh
shipped_before runs/generator_v12.safetensors generator_tiny.safetensors f4a776a  # generator v12
INIT=runs/generator_v12.safetensors OUT="${OUT:-runs/gen_v14}" SEED="${SEED:-9}" \
  EXTRA_ARGS="--input-render-weight 2 ${GROW:---grow-image-matching 5} ${EXTRA_ARGS:-}" \
  exec scripts/train_generator_v8.sh "${1:-3500}"
