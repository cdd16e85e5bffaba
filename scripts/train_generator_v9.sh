#!/usr/bin/env bash
# Generator v9 (shipped at this run's step 3,500, BENCHMARKS "Generator v9"; re-running goes on
# toward STEPS, the next candidate): v8 fine-tuned for STEPS more steps with v8's recipe
# (scripts/train_generator_v8.sh: v7's losses, 64 and 128 px, half of the 128-px steps on
# windows of other shapes, a weight average of decay 0.998) and a new batch seed (3). v8 is
# taken from the commit that shipped it (4e61949), so a fresh clone starts from the right
# weights. Same data choices as v8 (SCENES / SUBSET; default: v7's 420 scenes).
# ~1.3 s a step on one thread. Resumable: re-run to go on.
#   OUT=runs/gen_v9 [SEED=3] [FRAME_PROB=0.5] [EMA=0.998] [SCENES=... SUBSET=...] \
#     scripts/train_generator_v9.sh [STEPS]
# Check it before it ships: scripts/eval_generator.sh v9 runs/gen_v9/checkpoint.safetensors \
#   depth ladder ladder256 fox (the fox part scores 7 choices of inputs at 64 and 128 px).
set -euo pipefail
cd "$(dirname "$0")/.."
. scripts/shipped_before.sh
shipped_before runs/generator_v8.safetensors generator_tiny.safetensors 4e61949  # generator v8
INIT=runs/generator_v8.safetensors OUT="${OUT:-runs/gen_v9}" SEED="${SEED:-3}" \
  exec scripts/train_generator_v8.sh "${1:-5000}"
