#!/usr/bin/env bash
# Stage 2 v10 (candidate): stage 2 v9's recipe and data (v7 fine-tuned on generator v5's
# renders) plus the shift term: half of each batch is the other half's crops moved 1-7 px,
# and the outputs must agree where they overlap (--shift-weight; prosplat.train.augment).
# v9 adds an 8-px lattice to every view (BENCHMARKS); the term asks for an answer that does
# not depend on where a pixel sits in the VAE's 8-px cells. Resumable like v9.
#   scripts/train_stage2_v10.sh [STEPS]   (default 3000; WEIGHT= the shift weight, default 10)
set -euo pipefail
cd "$(dirname "$0")/.."
OUT=${OUT:-runs/s2v10/shift} exec scripts/train_stage2_v9.sh "${1:-3000}" --shift-weight "${WEIGHT:-10}"
