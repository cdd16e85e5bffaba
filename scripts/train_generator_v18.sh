#!/usr/bin/env bash
# Generator v18 candidate: the shipped v16 grown by learned depth upsampling
# (--grow-convex-upsampling: each full-resolution pixel reweights the four 1/4-resolution
# depths bilinear interpolation reads, starting at bilinear) and trained on with v16's recipe
# (train_generator_v17.sh: the input cameras' render term at 2, --fill-holes) on exactly
# v17b's scenes and batch seed (render rounds 7-8: family seeds 10420-10539 and their 24 hard
# scenes, seed 14), so v18 against v17b is the upsampling's effect alone.
# Why: Blender's true depth averaged to 1/4 resolution and upsampled bilinearly loses 2.0 dB
# of the true-depth bound at 128 px; the best of the same four samples per pixel loses 0.7
# (BENCHMARKS.md "Generator v18 candidate"). Two threads by default.
#   scripts/train_generator_v18.sh [STEPS]      (default 2500; OUT, SEED, SCENES, SUBSET
#   override)
# Resumable: the same command continues from OUT's last checkpoint.
set -euo pipefail
cd "$(dirname "$0")/.."
. scripts/scene_subset.sh
OMP_NUM_THREADS=${OMP_NUM_THREADS:-2} OUT="${OUT:-runs/gen_v18}" SEED="${SEED:-14}" \
  SCENES="${SCENES:-10420-10539 $(hard_rounds 9 7)}" SUBSET="${SUBSET:-data/gen_v17b}" \
  EXTRA_ARGS="--grow-convex-upsampling ${EXTRA_ARGS:-}" \
  exec scripts/train_generator_v17.sh "${1:-2500}"
