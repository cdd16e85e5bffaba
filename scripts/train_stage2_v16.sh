#!/usr/bin/env bash
# Stage 2 v16 candidates: v13 fine-tuned on renders whose holes are filled from their own
# colours before the model sees them (`--fill`, ImproveConfig.fill_input,
# prosplat.render.hole_fill), against the same fine-tune without the fill (ARM=ctrl), so the
# paired difference is the fill's. Why: on the test ladder the pull-push fill alone puts the
# raw render at 19.56 / 18.66 dB (64 / 128 px, black holes: 16.42 / 15.16), and blending
# v13's output with it where alpha < 1 gains +0.15 / +0.14 dB: stage 2 paints holes worse
# than the fill does (BENCHMARKS "Holes in the raw render").
#   1. data/train128: the training scenes rendered so far (scripts/render_v2_data.sh train);
#   2. raw64 (2/3/4/6 inputs) and raw128 (2/4) curated with the shipped generator (v7) at up
#      to 128 px, as the pipeline runs it (scripts/curate_stage2_sets.sh; kept when present);
#   3. v13 + STEPS steps with v12's recipe (warp, alpha, 48-px crops, flips, the sub-pixel
#      shift term) at LPIPS weight LPIPS (default 0.5), one set per step.
# Resumable: re-running continues the run.
#   ARM=fill|ctrl scripts/train_stage2_v16.sh [STEPS]   (default fill, 2000 steps;
#   SETS= the curated sets' folder, default runs/s2v16/sets; OUT= default runs/s2v16/ARM)
set -euo pipefail
cd "$(dirname "$0")/.."
ARM=${ARM:-fill}
case "$ARM" in
  fill) EXTRA=--fill ;;
  ctrl) EXTRA= ;;
  *) echo "train_stage2_v16.sh: ARM must be fill or ctrl, got $ARM" >&2; exit 1 ;;
esac
INIT=${INIT:-runs/s2v16/v13.safetensors}
. scripts/shipped_before.sh
shipped_before "$INIT" improve_tiny.safetensors 7ab5437  # stage 2 v13
USE256=0 INIT="$INIT" SETS="${SETS:-runs/s2v16/sets}" OUT="${OUT:-runs/s2v16/$ARM}" \
  LPIPS="${LPIPS:-0.5}" EXTRA_ARGS="$EXTRA" exec scripts/train_stage2_v12.sh "${1:-2000}"
