#!/usr/bin/env bash
# Generator v16 candidates: the shipped v14 trained on with its own recipe (v8's, the input
# cameras' render term at 2, the images' own plane sweep already grown in), every render
# scored with its holes filled by pull-push (--fill-holes) instead of black: the loss then
# scores what the raw view and stage 2 see, and no longer rewards spilling Gaussians over
# what no input saw (BENCHMARKS "Holes").
#   v16a (default): --fill-holes, seed 12;
#   the control is v15a (v14's recipe without the fill, seed 11); both are scored in
#   BENCHMARKS "Generator v16a" and "Generator v15a".
#   scripts/train_generator_v16.sh [STEPS]      (OUT, SEED, EXTRA_ARGS override)
# ~1.2 s a step on one thread. Resumable: the same command continues from OUT's last checkpoint.
set -euo pipefail
cd "$(dirname "$0")/.."
. scripts/shipped_before.sh
shipped_before runs/generator_v14a.safetensors generator_tiny.safetensors 9db7f27  # generator v14
INIT=runs/generator_v14a.safetensors OUT="${OUT:-runs/gen_v16a}" SEED="${SEED:-12}" \
  EXTRA_ARGS="--input-render-weight 2 --fill-holes ${EXTRA_ARGS:-}" \
  exec scripts/train_generator_v8.sh "${1:-3500}"
