#!/usr/bin/env bash
# Stage 2 v17 candidate: v16's recipe (v13 + 2,000 steps on filled renders, `--fill`, LPIPS
# weight 0.1) on renders of the generator's Gaussians drawn at half their scales (`train
# curate --splat-scale 0.5`, what `render_view(..., splat_scale=SPLAT_SCALE)` gives the model),
# on the same 179 training scenes as v16, so v17 - v16 is the smaller splats' own effect. Why:
# the generator sizes its Gaussians to cover the gaps between them on black; with the gaps
# filled, half that footprint scores +0.5 dB filled and v16 itself gains ~0.1 dB on such
# renders untrained (BENCHMARKS "Splat scale").
#   1. SUBSET (default data/s2v16_scenes): links to v16's 179 scenes of data/train128 (family
#      seeds 10000-10154 and the 24 hard scenes of rounds 0-1; SCENES= other seed ranges);
#   2. raw64 (2/3/4/6 inputs) and raw128 (2/4) curated with the shipped generator (v7) at up
#      to 128 px, at SPLAT (default 0.5) (scripts/curate_stage2_sets.sh; kept when present);
#   3. v13 + STEPS steps with v16's recipe (scripts/train_stage2_v16.sh, ARM=fill).
# Resumable: re-running keeps the sets and continues the run.
#   scripts/train_stage2_v17.sh [STEPS]   (default 2000; SETS= default runs/s2v17/sets;
#   OUT= default runs/s2v17/run; LPIPS= default 0.1; SPLAT= default 0.5)
set -euo pipefail
cd "$(dirname "$0")/.."
SUBSET=${SUBSET:-data/s2v16_scenes}
SETS=${SETS:-runs/s2v17/sets}
. scripts/scene_subset.sh
scene_subset "$SUBSET" "${SCENES:-10000-10154 $(hard_rounds 2)}"
# exported: train_stage2_v12.sh (run below) curates any set still missing the same way
export SPLAT=${SPLAT:-0.5} DATA=$SUBSET GEN_SIZE=128
scripts/curate_stage2_sets.sh "$SETS" raw64 &
pid=$!
scripts/curate_stage2_sets.sh "$SETS" raw128
wait "$pid"  # a failed curation stops the run here
LPIPS=${LPIPS:-0.1} ARM=fill SETS="$SETS" OUT="${OUT:-runs/s2v17/run}" \
  exec scripts/train_stage2_v16.sh "${1:-2000}"
