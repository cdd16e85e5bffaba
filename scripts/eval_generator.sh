#!/usr/bin/env bash
# The checks a generator gets before it ships (BENCHMARKS "Generator v7"/"v8"), for one set of
# weights, each PART into runs/eval_<NAME>/ with its log, so parts can run side by side on the
# two cores (one thread each) and a candidate is scored beside the shipped weights on data
# rendered the same way:
#   depth    input-view depth AbsRel at 128 and 64 px (benchmarks/input_depth.py --no-sweep)
#   ladder   test ladder at 64 and 128 px: paste, raw, enhanced, and both with holes filled
#            (prosplat eval ladder; issue 12 scores the filled raw render, BENCHMARKS "Holes")
#   ladder256  the same at 256 px on data/test256
#   views    flicker along 24-frame paths and re-rendered input cameras at 64 and 128 px
#            (benchmarks/enhance_views.py --inputs-too)
#   fox      real photos: refine 300 + enhance at 64 and 128 px over 7 choices of 4 inputs
#            (prosplat eval posed --input-sets 7: one choice can swing a generator's result
#            by 0.7 dB; needs data/outside/fox from scripts/outside_data.sh)
# Data: scripts/render_v2_data.sh test (data/test128, data/test256). Stage 2: the shipped one.
# Pair two names' ladders with benchmarks/compare_ladders.py runs/eval_A/ladder/ladder.json
# runs/eval_B/ladder/ladder.json (a part run again writes ladder-2/, never over the first),
# and their fox runs with compare_ladders.py runs/eval_A/fox64/scores.json
# runs/eval_B/fox64/scores.json (whole choices of inputs resampled).
#   scripts/eval_generator.sh NAME WEIGHTS PART...     e.g.
#   scripts/eval_generator.sh v7 runs/generator_v7.safetensors depth ladder
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PY:-.venv/bin/python}
P=${PROSPLAT:-.venv/bin/prosplat}
export OMP_NUM_THREADS=${OMP_NUM_THREADS:-1}
name=${1:?usage: eval_generator.sh NAME WEIGHTS PART...}
weights=${2:?usage: eval_generator.sh NAME WEIGHTS PART...}
shift 2
[ -f "$weights" ] || { echo "eval_generator.sh: no weights at $weights" >&2; exit 1; }
out=runs/eval_$name
mkdir -p "$out"
for part in "$@"; do
  log=$out/$part.log
  echo "== $part -> $log"
  case $part in
  depth)
    for size in 128 64; do
      $PY benchmarks/input_depth.py --data data/test128 --size $size --views 4 --no-sweep \
        --generator "$name=$weights"
    done > "$log" 2>&1 ;;
  ladder)
    $P eval ladder --data data/test128 --sizes 64 128 --views 4 \
      --rows paste generator enhanced fill --generator "$weights" --out "$out/ladder" > "$log" 2>&1 ;;
  ladder256)
    $P eval ladder --data data/test256 --sizes 256 --views 4 \
      --rows paste generator enhanced fill --generator "$weights" --out "$out/ladder256" > "$log" 2>&1 ;;
  views)
    $PY benchmarks/enhance_views.py --data data/test128 --sizes 64 128 --views 4 \
      --working-sizes -1 --flicker-frames 24 --inputs-too --generator "$weights" \
      --out "$out/views" > "$log" 2>&1 ;;
  fox)
    for size in 64 128; do
      $P eval posed data/outside/fox --skip-missing --size $size --num-inputs 4 --targets 16 \
        --input-sets 7 --refine-steps 300 --weights "$weights" --out "$out/fox$size"
    done > "$log" 2>&1 ;;
  *) echo "eval_generator.sh: unknown part $part (depth ladder ladder256 views fox)" >&2; exit 1 ;;
  esac
done
