#!/usr/bin/env bash
# A generator candidate's capacity screen: does it fit scenes it trains on better than v16?
# STEPS (default 1,500) of v16's recipe (scripts/train_generator_v17.sh: the input cameras'
# render term at 2, --fill-holes) from the shipped v16 on 24 training scenes v16 itself saw
# (render round 0: family seeds 10000-10017 and the first scene of each hard kind, linked into
# data/seen24), then the ladder at 128 px and the input depth on those same 24 scenes.
# Why: on scenes it trained on, v16 lies as far under Gaussians at Blender's depth (1.70 dB)
# as on the test scenes (1.72), and 1,500 more steps on just those scenes close only 0.23 dB
# (BENCHMARKS "Seen scenes"): the generator is not short of data. A change that does not fit
# these scenes better will not generalise better, and this screen takes ~25 minutes on two
# threads where an A/B on new scenes and the test ladder take ~45.
#   scripts/screen_generator.sh NAME [STEPS]    (STEPS 0: score INIT as it is)
#   EXTRA_ARGS / LR / SEED pass to the recipe (e.g. EXTRA_ARGS="--grow-band 9"); INIT to
#   start elsewhere than v16 (train_generator_v17.sh's default).
# Two threads by default; beside anything else busy (the test suite, another run) set
# OMP_NUM_THREADS=1: two threads sharing a loaded core ran a step ~15x slower here (18 s, not 1.2).
# -> runs/screen_NAME/: the run (checkpoint.safetensors, log.jsonl), ladder/ (ladder.md), depth.log
# Compare with the v16 rows: scripts/screen_generator.sh v16 0 and scripts/screen_generator.sh
# v16recipe (the recipe alone). Resumable: the same command (the same EXTRA_ARGS) continues the
# run, then scores it.
set -euo pipefail
cd "$(dirname "$0")/.."
P=${PROSPLAT:-.venv/bin/prosplat}
PY=${PY:-.venv/bin/python}
name=${1:?usage: screen_generator.sh NAME [STEPS]}
steps=${2:-1500}
out=runs/screen_$name
SEEN="10000-10017 20000-20000 20100-20100 20200-20200 20300-20300 20400-20400 20500-20500"
export OMP_NUM_THREADS=${OMP_NUM_THREADS:-2}
mkdir -p "$out"
if [ "$steps" -gt 0 ]; then
  OUT="$out" SEED="${SEED:-21}" SCENES="$SEEN" SUBSET=data/seen24 \
    scripts/train_generator_v17.sh "$steps" > "$out/train.log" 2>&1
  weights=$out/checkpoint.safetensors
else
  . scripts/scene_subset.sh
  scene_subset data/seen24 "$SEEN"
  weights=${INIT:-prosplat/weights/generator_tiny.safetensors}
fi
[ -f "$out/ladder/ladder.json" ] || $P eval ladder --data data/seen24 --sizes 128 --views 4 \
  --rows paste generator enhanced fill --generator "$weights" --out "$out/ladder" \
  > "$out/ladder.log" 2>&1
[ -f "$out/depth.log" ] || $PY benchmarks/input_depth.py --data data/seen24 --size 128 \
  --views 4 --no-sweep --generator "$name=$weights" > "$out/depth.log" 2>&1
# the rows to read: filled and enhanced against the bound, then the depth (mean / median AbsRel)
grep -E '^\| (generator filled|enhanced|true depth filled) \|' "$out/ladder/ladder.md" | head -3 || true
grep -E "^\| $name \|" "$out/depth.log" | head -1 || true
