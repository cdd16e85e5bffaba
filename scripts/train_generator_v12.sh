#!/usr/bin/env bash
# Generator v12 (BENCHMARKS "Generator v12 candidates"; trained as v12b): v11 (taken from git
# history) fine-tuned for 3,500 more steps with v11's own recipe (v8's recipe on v7's 420
# scenes, the input cameras' render term at 2) and batch seed 7. ~1.2 s a step on one thread.
# Resumable: re-run the same command to go on.
#   OUT=runs/gen_v12 [SEED=7] [EXTRA_ARGS=...] scripts/train_generator_v12.sh [STEPS]
set -euo pipefail
cd "$(dirname "$0")/.."
. scripts/shipped_before.sh
shipped_before runs/generator_v11.safetensors generator_tiny.safetensors 1f071e3  # generator v11
INIT=runs/generator_v11.safetensors OUT="${OUT:-runs/gen_v12}" SEED="${SEED:-7}" \
  EXTRA_ARGS="--input-render-weight 2 ${EXTRA_ARGS:-}" exec scripts/train_generator_v8.sh "${1:-3500}"
