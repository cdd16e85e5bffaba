#!/usr/bin/env bash
# Generator v14 candidate: v12 grown by the images' own ZNCC plane sweep (window 5, at half the
# matching size; prosplat.generator.image_cost), entering through zero weights so step 0 is
# v12 exactly, then v12's recipe (v8's with the input cameras' render term at 2).
#   scripts/train_generator_v14.sh [STEPS]      (OUT, SEED, WINDOW, EXTRA_ARGS override)
# Resumable: the same command continues from OUT's last checkpoint.
set -euo pipefail
cd "$(dirname "$0")/.."
. scripts/shipped_before.sh
shipped_before runs/generator_v12.safetensors generator_tiny.safetensors f4a776a  # generator v12
INIT=runs/generator_v12.safetensors OUT="${OUT:-runs/gen_v14}" SEED="${SEED:-9}" \
  EXTRA_ARGS="--input-render-weight 2 --grow-image-matching ${WINDOW:-5} ${EXTRA_ARGS:-}" \
  exec scripts/train_generator_v8.sh "${1:-3500}"
