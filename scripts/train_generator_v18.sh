#!/usr/bin/env bash
# Generator v18 candidate: the shipped v16 grown by three dilated residual blocks at the end of
# its full-resolution depth refiner (--grow-refine-context 3: dilations 2, 4, 8, each block
# the identity at the start, receptive field 9 -> 65 px) and trained on with v16's recipe
# (train_generator_v17.sh: the input cameras' render term at 2, --fill-holes) on exactly
# v17b's scenes and batch seed (render rounds 7-8: family seeds 10420-10539 and their 24 hard
# scenes, seed 14), so v18 against v17b is the blocks' effect alone.
# Why: the refiner's correction is worth 2.1 dB at 128 px (v16 without it: 17.93 dB filled
# against 20.04), v16's depth fed through its own adapter at Blender's true values scores
# 21.63, and its 1/4-resolution depth is smooth across 8-12 px at silhouettes, wider than the
# refiner's 9-px view (BENCHMARKS.md "Generator v18 candidate"). Two threads by default.
#   scripts/train_generator_v18.sh [STEPS]      (default 2500; OUT, SEED, SCENES, SUBSET,
#   BLOCKS override)
# Resumable: the same command continues from OUT's last checkpoint.
set -euo pipefail
cd "$(dirname "$0")/.."
. scripts/scene_subset.sh
OMP_NUM_THREADS=${OMP_NUM_THREADS:-2} OUT="${OUT:-runs/gen_v18}" SEED="${SEED:-14}" \
  SCENES="${SCENES:-10420-10539 $(hard_rounds 9 7)}" SUBSET="${SUBSET:-data/gen_v17b}" \
  EXTRA_ARGS="--grow-refine-context ${BLOCKS:-3} ${EXTRA_ARGS:-}" \
  exec scripts/train_generator_v17.sh "${1:-2500}"
