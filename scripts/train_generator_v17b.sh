#!/usr/bin/env bash
# Generator v17b candidate: the shipped v16 trained on with its own recipe (train_generator_v17.sh:
# the input cameras' render term at 2, --fill-holes) on the 144 scenes of render rounds 7-8
# alone (family seeds 10420-10539 and their 24 hard scenes; v16 saw none of them), batch seed
# 14. Why: v17a (527 scenes, rounds 0-7) needs 2.4 hours of rendering from an empty data/
# first; rounds 7-8 (`scripts/render_v2_data.sh train 9 7`) render in about 35 minutes, so
# this is the new scenes' effect that one sitting can measure. Two threads by default.
#   scripts/train_generator_v17b.sh [STEPS]     (default 2500; OUT, SEED, SCENES, SUBSET
#   override)
# Resumable: the same command continues from OUT's last checkpoint.
set -euo pipefail
cd "$(dirname "$0")/.."
. scripts/scene_subset.sh
OMP_NUM_THREADS=${OMP_NUM_THREADS:-2} OUT="${OUT:-runs/gen_v17b}" SEED="${SEED:-14}" \
  SCENES="${SCENES:-10420-10539 $(hard_rounds 9 7)}" SUBSET="${SUBSET:-data/gen_v17b}" \
  exec scripts/train_generator_v17.sh "${1:-2500}"
