#!/usr/bin/env bash
# Generator v10 candidates (BENCHMARKS "Generator v10"): the shipped v9 fine-tuned for STEPS
# more steps with v8's recipe (scripts/train_generator_v8.sh: v7's losses, 64 and 128 px,
# half of the 128-px steps on windows of other shapes, a weight average of decay 0.998) on v7's
# 420 scenes. v9 is taken from the commit that shipped it (f500176), so a fresh clone starts
# from the right weights.
#   v10  : batch seed 4, the recipe as it is
#   v10b : batch seed 5 and the input cameras' render term at 2 instead of 0.5 (issue 12's
#          re-rendered-inputs bar): SEED=5 OUT=runs/gen_v10b EXTRA_ARGS="--input-render-weight 2"
# ~1.2 s a step on one thread. Resumable: re-run the same command to go on.
#   OUT=runs/gen_v10 [SEED=4] [EXTRA_ARGS=...] scripts/train_generator_v10.sh [STEPS]
# Score a candidate before it ships: scripts/eval_generator.sh NAME runs/gen_v10/checkpoint.safetensors \
#   depth ladder ladder256 fox
set -euo pipefail
cd "$(dirname "$0")/.."
. scripts/shipped_before.sh
shipped_before runs/generator_v9.safetensors generator_tiny.safetensors f500176  # generator v9
INIT=runs/generator_v9.safetensors OUT="${OUT:-runs/gen_v10}" SEED="${SEED:-4}" \
  exec scripts/train_generator_v8.sh "${1:-5000}"
