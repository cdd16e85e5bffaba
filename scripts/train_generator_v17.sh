#!/usr/bin/env bash
# Generator v17 candidate: the shipped v16 trained on with its own recipe (v8's, the input
# cameras' render term at 2, every render scored with its holes filled: --fill-holes) on every
# training scene rendered so far that the scene subset names: the 420 scenes v16 saw plus the
# 107 of render rounds 5-6 (family seeds 10360-10442 and their hard scenes), batch seed 13.
# Why: v16's recipe had 3,500 steps from v14 (v15a showed v14's own recipe had levelled off;
# v16's has not been run longer), and more scenes is issue 12's first lever. Stage 2 v22 was
# fine-tuned on v16's renders of the 107 new scenes, so a v17 pairs with v22 or its retrain.
#   scripts/train_generator_v17.sh [STEPS]      (default 3500; OUT, SEED, SCENES, SUBSET,
#   EXTRA_ARGS override)
# ~1.2 s a step on one thread. Resumable: the same command continues from OUT's last checkpoint.
set -euo pipefail
cd "$(dirname "$0")/.."
. scripts/shipped_before.sh
. scripts/scene_subset.sh
shipped_before runs/generator_v16.safetensors generator_tiny.safetensors e1a5d0b  # generator v16
INIT=runs/generator_v16.safetensors OUT="${OUT:-runs/gen_v17a}" SEED="${SEED:-13}" \
  SCENES="${SCENES:-10000-10442 $(hard_rounds 7)}" SUBSET="${SUBSET:-data/gen_v17}" \
  EXTRA_ARGS="--input-render-weight 2 --fill-holes ${EXTRA_ARGS:-}" \
  exec scripts/train_generator_v8.sh "${1:-3500}"
