#!/usr/bin/env bash
# Stage 2 v25 candidate (level on the test scenes, -0.2 dB on the fox photos: not shipped;
# BENCHMARKS "Views favour the nearest input"): the shipped v22 fine-tuned with v22's recipe
# on the shipped generator v16's renders whose colour favours the input MORI picks for each
# target (`train curate --other-views-opacity`, default prosplat.enhance.OTHER_VIEWS_OPACITY),
# as every view now renders. Why: favouring the nearest input lifts the filled raw view by +0.31 dB at 128 px but
# v22's enhanced view by only +0.09 (BENCHMARKS "Views favour the nearest input"), and each
# stage 2 so far gained most from matching the renders it enhances.
#   scenes: family seeds 10540-10636 and the hard scenes of render rounds 9-10 (121 scenes
#           no model trained on: v16 and v22 saw seeds up to 10442 and rounds 0-6, the v24
#           candidate 10443-10539 and rounds 7-8), rendered by scripts/render_v2_data.sh
#           train 11 9;
#   sets: raw64 (2/4 inputs), raw128 (4), ref64 (2/4, refined 100 steps), generator v16 at
#         128 px;
#   training: v22's (lr 5e-5, batch 8, seed 22).
#   scripts/train_stage2_v25.sh [STEPS]   (default 2000; GEN= default v16 from git history;
#   SCENES, SUBSET, SETS, OUT override)
# Resumable: finished sets are kept and re-running continues the training run.
set -euo pipefail
cd "$(dirname "$0")/.."
. scripts/shipped_before.sh
. scripts/scene_subset.sh
shipped_before runs/s2v25/v22.safetensors improve_tiny.safetensors e1a5d0b  # stage 2 v22
shipped_before runs/s2v25/v16.safetensors generator_tiny.safetensors e1a5d0b  # generator v16
GEN="${GEN:-runs/s2v25/v16.safetensors}" INIT=runs/s2v25/v22.safetensors \
  SUBSET="${SUBSET:-data/s2v25_scenes}" SETS="${SETS:-runs/s2v25/sets}" \
  OUT="${OUT:-runs/s2v25/run}" SCENES="${SCENES:-10540-10636 $(hard_rounds 11 9)}" \
  SPECS="raw64:2,4:64:0 raw128:4:128:0 ref64:2,4:64:100" \
  exec scripts/train_stage2_v22.sh "${1:-2000}"
