#!/usr/bin/env bash
# Generator v19 candidate: the shipped v16 trained on with its own recipe (train_generator_v17.sh:
# the input cameras' render term at 2, --fill-holes) on every scene of the full training set:
# the 2,016 scenes of render rounds 0-27 (`scripts/render_v2_data.sh train 28`; family seeds
# 10000-11679 and 56 of each hard scene), batch seed 19. Why: issue 12's first lever is data at
# scale. v16 saw 420 scenes and v17b 144 new ones (level); at one scene a step, 3,500 steps
# see each of the 2,016 about 1.7 times. Two threads by default.
#   scripts/train_generator_v19.sh [STEPS]     (default 3500; OUT, SEED, SCENES, SUBSET
#   override)
# ~0.7 s a step on two threads. Resumable: the same command continues from OUT's last checkpoint.
set -euo pipefail
cd "$(dirname "$0")/.."
. scripts/scene_subset.sh
OMP_NUM_THREADS=${OMP_NUM_THREADS:-2} OUT="${OUT:-runs/gen_v19}" SEED="${SEED:-19}" \
  SCENES="${SCENES:-10000-11679 $(hard_rounds 28)}" SUBSET="${SUBSET:-data/gen_v19}" \
  exec scripts/train_generator_v17.sh "${1:-3500}"
