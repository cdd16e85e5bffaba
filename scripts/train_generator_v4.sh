#!/usr/bin/env bash
# Generator v4: v3 fine-tuned for geometry, in two parts of one thread each (~25 min each
# with two runs sharing this 2-core machine):
#   a: 3,000 steps with the depth terms compared in log depth (--depth-loss log, scale-free)
#      at 3x v3's input-depth weight, on the 132 scenes rendered when it started;
#   b: 5,000 more steps, the same recipe, on the 246 scenes rendered by then.
# Why: v3's input-view depth was no better than a constant on the test split (mean AbsRel
# 0.508 against 0.512) nor on its own training scenes: it underfit depth, whose terms were
# too weak beside the photometric ones (BENCHMARKS "Generator v4").
# Resumable: re-run to go on (each part keeps its run folder).
#   scripts/train_generator_v4.sh   (INIT= the starting weights, default v3 from git history)
set -euo pipefail
cd "$(dirname "$0")/.."
P=${PROSPLAT:-.venv/bin/prosplat}
export OMP_NUM_THREADS=${OMP_NUM_THREADS:-1}
INIT=${INIT:-runs/generator_v3.safetensors}
. scripts/shipped_before.sh
. scripts/scene_subset.sh
shipped_before "$INIT" generator_tiny.safetensors 00a9ef7  # generator v3
COMMON=(--val data/val128 --sizes 64 --any-view --inputs 2,3,4,5,6 --targets 2 --lr 1.5e-4
  --input-depth-weight 1 --depth-weight 0.1 --depth-loss log --input-render-weight 0.5
  --target-scale 2 --warmup 100 --save-every 250 --log-every 50 --val-every 1000
  --val-scenes 8 --cache-scenes 256)
scene_subset data/gen_v4a "10000-10119 $(hard_rounds 1)"
$P train generator --data data/gen_v4a --init "$INIT" --out runs/gen_v4log --steps 3000 \
  "${COMMON[@]}"
cp runs/gen_v4log/checkpoint.safetensors runs/gen_v4log.safetensors
scene_subset data/gen_v4b "10000-10209 $(hard_rounds 3)"
$P train generator --data data/gen_v4b --init runs/gen_v4log.safetensors \
  --out runs/gen_v4b_nobg --steps 5000 "${COMMON[@]}"
cp runs/gen_v4b_nobg/checkpoint.safetensors runs/generator_v4.safetensors
