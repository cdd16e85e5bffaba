#!/usr/bin/env bash
# Stage 2 v22 candidate: v19 fine-tuned on the CPU on generator v16a's renders. Why: v16a
# (`train generator --fill-holes`) leaves holes where no input saw, and its filled raw view
# gains ~0.5 dB over v14, but v19, trained on generators that cover those parts, loses 0.3 /
# 0.2 dB enhancing it (BENCHMARKS "Generator v16a"). The renders are the capped views stage 2
# gets at inference (`train curate --max-splat-radius`, default MAX_SPLAT_RADIUS).
#   1. SUBSET (default data/s2v22_scenes): links to the 107 scenes of data/train128 that
#      neither v16a nor any stage 2 trained on (family seeds 10360-10442 and the hard scenes
#      of render rounds 5-6; SCENES= other seed ranges);
#   2. raw64 (2/4 inputs), raw128 (4) and ref64 (2/4, the generator's Gaussians refined 100
#      steps by prosplat.refine) curated with GEN (default runs/generator_v16a.safetensors)
#      at up to 128 px, as the pipeline runs it: two processes of one thread, each taking
#      every second set (SPECS= other sets, NAME:VIEWS:SIZE:REFINE_STEPS each);
#   3. v19 + STEPS steps with v19's recipe (warp, alpha, fill, 48-px crops, flips, the
#      sub-pixel shift term, LPIPS 0.1, working size 256) at batch 8 and lr 5e-5 (stage 2
#      v20's CPU fine-tune), seed 22.
# Resumable: finished sets are kept and re-running continues the training run.
#   scripts/train_stage2_v22.sh [STEPS]   (default 2000; SETS= default runs/s2v22/sets;
#   OUT= default runs/s2v22/run; INIT= default v19 from git history)
set -euo pipefail
cd "$(dirname "$0")/.."
P=${PROSPLAT:-.venv/bin/prosplat}
SUBSET=${SUBSET:-data/s2v22_scenes}
SETS=${SETS:-runs/s2v22/sets}
OUT=${OUT:-runs/s2v22/run}
GEN=${GEN:-runs/generator_v16a.safetensors}
INIT=${INIT:-runs/s2v22/v19.safetensors}
[ -f "$GEN" ] || { echo "train_stage2_v22.sh: no generator $GEN" >&2; exit 1; }
. scripts/shipped_before.sh
shipped_before "$INIT" improve_tiny.safetensors 0401317  # stage 2 v19
. scripts/scene_subset.sh
scene_subset "$SUBSET" "${SCENES:-10360-10442 $(hard_rounds 7 5)}"
read -r -a specs <<< "${SPECS:-raw64:2,4:64:0 raw128:4:128:0 ref64:2,4:64:100}"
mkdir -p "$SETS"
curate() {  # NAME:VIEWS:SIZE:REFINE_STEPS ...: each set in turn, kept when present
  local spec name views size steps
  for spec in "$@"; do
    IFS=: read -r name views size steps <<< "$spec"
    [ -f "$SETS/$name.safetensors" ] || OMP_NUM_THREADS=1 $P train curate --data "$SUBSET" \
      --out "$SETS/$name.safetensors" --generator "$GEN" --generator-size 128 \
      --views "$views" --size "$size" --refine-steps "$steps" || return 1
  done
}
even=() odd=() data=()
for i in "${!specs[@]}"; do
  if ((i % 2)); then odd+=("${specs[$i]}"); else even+=("${specs[$i]}"); fi
  data+=("$SETS/${specs[$i]%%:*}.safetensors")
done
curate "${odd[@]}" &
pid=$!
curate "${even[@]}"
wait "$pid"  # a failed curation stops the run here
OMP_NUM_THREADS=${OMP_NUM_THREADS:-2} $P train improve --data "$(IFS=,; echo "${data[*]}")" \
  --out "$OUT" --init "$INIT" --warp --padding replicate --alpha --fill --crop 48 --flip \
  --steps "${1:-2000}" --batch 8 --lr 5e-5 --warmup 100 --lpips-weight 0.1 --shift-weight 10 \
  --subpixel-shift --working-size 256 --seed 22 --save-every 100 --log-every 50
