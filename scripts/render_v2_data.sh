#!/usr/bin/env bash
# The v2 data sets (generator v2, the evaluation ladder), rendered with Cycles on the CPU.
# Re-running completes a partial set: finished scene folders are skipped.
#   val128   8 validation scenes, 128 px, 16 views each (6 inputs + 10 targets)
#   test128  6 hard + 18 family test scenes (seeds 950100-5, 987000-17), 128 px, 6 inputs +
#            8 targets (evaluated at 64 and 128)
#   test256  the first 6 family test scenes again at 256 px (evaluated at 256); with ALL256=1
#            all 24 test scenes
#   train128 training scenes, 128 px, 16 views each, in rounds of 60 family scenes + 2 of
#            each hard scene, so a run stopped at any point has every kind
# Colour: Cycles' denoiser after SAMPLES samples (default 8). Against 512-sample renders
# (BENCHMARKS "Scene rendering"), 8 samples + denoiser give 29-37 dB and 16 + denoiser 31-39
# dB at 0.6x the time per view; every model here is below 21 dB, so the noise left is far
# below the error it learns from. Scenes rendered before 2026-11-24 used 16 (the scene's
# transforms.json records its samples). Training scenes use the denoiser's fast settings
# (DENOISE_QUALITY=fast, the default for train; high for eval and test, as those sets were
# rendered): 0.7-0.8x the colour render's time, 0.1-0.9 dB from high at 30-38 dB (BENCHMARKS
# "Faster training renders"). Older training scenes used high; transforms.json records which.
# Usage: scripts/render_v2_data.sh eval|test|train [ROUNDS [FIRST]]  (eval: val128, test128
# and test256; test: test128 and test256 only; train: rounds FIRST..ROUNDS-1, default 0..39 =
# 2,880 scenes; e.g. `train 9 7` renders rounds 7 and 8 only).
# The parts can run at once (WORKERS=1 each).
# THREADS=N: Cycles threads per worker (default: the cores / WORKERS), e.g. 1 beside a
# one-thread training run.
set -euo pipefail
cd "$(dirname "$0")/.."
P=${PROSPLAT:-.venv/bin/prosplat}
SAMPLES=${SAMPLES:-8}
HARD="textureless specular near_far thin_structures repeated_pattern inside_outside"
R="$P scenes render --samples $SAMPLES --denoise --workers ${WORKERS:-2} ${THREADS:+--threads $THREADS}"
part=${1:?usage: render_v2_data.sh eval|test|train [ROUNDS [FIRST]]}
hard_tests() {  # SIZE OUT: the 6 hard test scenes, seeds 950100-5
  local seed=950100 s
  for s in $HARD; do
    $R --seed $seed --count 1 --scene $s --size $1 --inputs 6 --targets 8 --out $2
    seed=$((seed + 1))
  done
}
if [ "$part" = eval ] || [ "$part" = test ]; then
[ "$part" = test ] || $R --seed 900000 --count 8 --size 128 --inputs 6 --targets 10 --out data/val128
hard_tests 128 data/test128
$R --seed 987000 --count 18 --size 128 --inputs 6 --targets 8 --out data/test128
$R --seed 987000 --count 6 --size 256 --inputs 6 --targets 8 --out data/test256
[ "${ALL256:-0}" = 1 ] || exit 0
# ALL256=1: the other 18 test scenes at 256 px too (issue 14: every family and hard scene at
# 64, 128 and 256 px), the first 6 family scenes first so a stopped run still has them
$R --seed 987006 --count 12 --size 256 --inputs 6 --targets 8 --out data/test256
hard_tests 256 data/test256
exit 0
fi
[ "$part" = train ] || { echo "render_v2_data.sh: unknown part $part (eval, test, train)" >&2; exit 1; }
R="$R --denoise-quality ${DENOISE_QUALITY:-fast}"
# A finished round is passed over here, without starting prosplat (which takes seconds to
# import torch, a minute or more a round on a busy machine).
. scripts/scene_subset.sh
rendered() {  # FIRST COUNT: is there a scene for every seed FIRST..FIRST+COUNT-1?
  local seed
  for seed in $(seq "$1" $(($1 + $2 - 1))); do
    train_scene "$seed" > /dev/null || return 1
  done
}
for round in $(seq "${3:-0}" $((${2:-40} - 1))); do
  first=$((10000 + 60 * round))
  rendered $first 60 ||
    $R --seed $first --count 60 --size 128 --inputs 6 --targets 10 --out data/train128
  i=0
  for s in $HARD; do
    first=$((20000 + 100 * i + 2 * round))
    rendered $first 2 ||
      $R --seed $first --count 2 --scene $s --size 128 --inputs 6 --targets 10 --out data/train128
    i=$((i + 1))
  done
done
