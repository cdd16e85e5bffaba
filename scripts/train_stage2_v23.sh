#!/usr/bin/env bash
# Stage 2 v23 candidate: the shipped v22 fine-tuned with v22's own recipe on generator v17a's
# renders of training scenes v17a never saw. Why: v22 learned v16's renders (BENCHMARKS
# "Generator v16 and stage 2 v22"); a generator trained on more scenes renders differently,
# and each stage 2 so far gained most from matching the renders it enhances.
#   scenes: family seeds 10443-10719 and the hard scenes of render rounds 7-11 (v17a trained on
#           seeds 10000-10442 and rounds 0-6: scripts/train_generator_v17.sh), rendered by
#           scripts/render_v2_data.sh train 12;
#   sets and training: scripts/train_stage2_v22.sh (raw64, raw128, ref64; lr 5e-5, seed 22).
#   scripts/train_stage2_v23.sh [STEPS]   (default 2000; GEN= default
#   runs/gen_v17a/checkpoint.safetensors; SCENES, SUBSET, SETS, OUT override)
# Resumable: finished sets are kept and re-running continues the training run.
set -euo pipefail
cd "$(dirname "$0")/.."
. scripts/shipped_before.sh
. scripts/scene_subset.sh
shipped_before runs/s2v23/v22.safetensors improve_tiny.safetensors e1a5d0b  # stage 2 v22
GEN="${GEN:-runs/gen_v17a/checkpoint.safetensors}" INIT=runs/s2v23/v22.safetensors \
  SUBSET="${SUBSET:-data/s2v23_scenes}" SETS="${SETS:-runs/s2v23/sets}" \
  OUT="${OUT:-runs/s2v23/run}" SCENES="${SCENES:-10443-10719 $(hard_rounds 12 7)}" \
  exec scripts/train_stage2_v22.sh "${1:-2000}"
