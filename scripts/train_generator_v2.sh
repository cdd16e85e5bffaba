#!/usr/bin/env bash
# Generator v2 (tiny) on the CPU, from the shipped v1, in two parts (BENCHMARKS "Generator v2
# on the CPU"). Both parts draw 2-6 inputs and the targets from any of a scene's 16 views
# (--any-view), run the generator at 64 px (the size the pipeline runs it at) and add the
# geometry terms: Blender's depth for the inputs' depth maps and for the rendered targets, and
# every input camera re-rendered from all views' Gaussians (the views must agree).
#   a: 5,000 steps of a 12,000-step cosine schedule, targets at 64 px. The views stop fogging
#      over each other (depth AbsRel 0.58 -> 0.47) but the Gaussians shrink to pinholes that
#      leave a dotted lattice on a 128-px camera.
#   b: from a's weights, targets rendered at 128 px (--target-scale 2): the same Gaussians now
#      have to cover a camera with 4x their pixels, as the pipeline renders them.
# Each part runs with one thread (two runs fit this 2-core machine) and is resumable:
# re-running skips a finished part and continues a stopped one.
#   scripts/train_generator_v2.sh   (data: scripts/render_v2_data.sh eval; ... train 2;
#   V1= the starting weights, default v1 taken from git history into runs/)
set -euo pipefail
cd "$(dirname "$0")/.."
P=${PROSPLAT:-.venv/bin/prosplat}
export OMP_NUM_THREADS=${OMP_NUM_THREADS:-1}
C="--data data/train128 --val data/val128 --config tiny --sizes 64 --any-view --inputs 2,3,4,5,6
   --targets 2 --lr 1.5e-4 --input-depth-weight 0.3 --depth-weight 0.1 --input-render-weight 0.5
   --log-every 50 --val-every 1000 --val-scenes 8"
# v1, the starting point, as shipped until v2 (from git history: the file in the tree is v2 now)
V1=${V1:-runs/generator_v1.safetensors}
[ -f "$V1" ] || { mkdir -p "$(dirname "$V1")"; git show 1f6739a:prosplat/weights/generator_tiny.safetensors > "$V1"; }
$P train generator $C --out runs/gen_v2cpu_b --init "$V1" \
  --warmup 200 --steps 12000 --stop-at 5000 --save-every 500
[ -f runs/genB5000.safetensors ] || cp runs/gen_v2cpu_b/checkpoint.safetensors runs/genB5000.safetensors
$P train generator $C --out runs/gen_v2cpu_c --init runs/genB5000.safetensors --target-scale 2 \
  --warmup 100 --steps 6000 --save-every 250
