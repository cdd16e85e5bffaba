#!/usr/bin/env bash
# Generator v6 candidates: v5 fine-tuned for STEPS more steps with v5's recipe on the scenes
# of data/train128 (seeds 10000-10359 and 10 of each hard scene, all of them scenes v5
# also trained on), at 64 and 128 px.
#   GROW_ALEXNET=3 : v5 grown by frozen AlexNet relu1-3 features (the LPIPS backbone, the one
#                    pretrained CNN here) added to the monocular branch through zero weights,
#                    so step 0 is v5 (prosplat.generator.grow.grow_alexnet)
#   GROW_ALEXNET=0 : the control, the same steps and batches without them
# LR (default 1.5e-4) and EXTRA_ARGS (more `train generator` flags) are for the runs that
# continue this recipe (scripts/train_generator_v7.sh). SCENES (seed ranges of data/train128,
# default "10000-10359 $(hard_rounds 5)") and SUBSET (the folder of links to them, default
# data/gen_v6) train on another set of scenes, e.g. the first rounds of a partly rendered set.
# ~1 s a step on one thread. Resumable: re-run to go on (the run folder keeps its state).
#   GROW_ALEXNET=3|0 OUT=runs/gen_v6a [INIT=...] [SEED=0] scripts/train_generator_v6.sh [STEPS]
set -euo pipefail
cd "$(dirname "$0")/.."
P=${PROSPLAT:-.venv/bin/prosplat}
export OMP_NUM_THREADS=${OMP_NUM_THREADS:-1}
GROW_ALEXNET=${GROW_ALEXNET:-3}
OUT=${OUT:-runs/gen_v6a}
. scripts/shipped_before.sh
. scripts/scene_subset.sh
# the default start is fetched from git history; an INIT the caller names must exist (train
# generator says so), never silently replaced by these weights
if [ -z "${INIT:-}" ]; then
  INIT=runs/generator_v5.safetensors
  shipped_before "$INIT" generator_tiny.safetensors 9665e28  # generator v5
fi
SUBSET=${SUBSET:-data/gen_v6}
scene_subset "$SUBSET" "${SCENES:-10000-10359 $(hard_rounds 5)}"
grow=()
[ "$GROW_ALEXNET" -gt 0 ] && grow=(--grow-alexnet "$GROW_ALEXNET")
read -r -a extra <<< "${EXTRA_ARGS:-}"
$P train generator --data "$SUBSET" --init "$INIT" --out "$OUT" --steps "${1:-3000}" \
  "${grow[@]}" --sizes 64,128 --any-view --inputs 2,3,4,5,6 --targets 2 --lr "${LR:-1.5e-4}" \
  --input-depth-weight 1 --depth-weight 0.1 --depth-loss log --input-render-weight 0.5 \
  --target-scale 2 --warmup 100 --save-every 250 --log-every 50 --cache-scenes 512 \
  --seed "${SEED:-0}" "${extra[@]}"
