#!/usr/bin/env bash
# Generator v13 candidates (BENCHMARKS "Generator v13"): v12 grown by the 1/2-resolution band
# search (--grow-cascade N, prosplat/generator/cascade.py; its correction starts at 0, so step 0
# is v12) and fine-tuned with v12's recipe (v8's on v7's 420 scenes, the input cameras' render
# term at 2). ~1.3 s a step on one thread. Resumable: re-run the same command to go on.
#   OUT=runs/gen_v13 [SEED=8] [CASCADE=9] [EXTRA_ARGS=...] scripts/train_generator_v13.sh [STEPS]
set -euo pipefail
cd "$(dirname "$0")/.."
. scripts/shipped_before.sh
shipped_before runs/generator_v12.safetensors generator_tiny.safetensors f4a776a  # generator v12
INIT=runs/generator_v12.safetensors OUT="${OUT:-runs/gen_v13}" SEED="${SEED:-8}" \
  EXTRA_ARGS="--input-render-weight 2 --grow-cascade ${CASCADE:-9} ${EXTRA_ARGS:-}" \
  exec scripts/train_generator_v8.sh "${1:-3500}"
