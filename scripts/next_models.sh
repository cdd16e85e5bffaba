#!/usr/bin/env bash
# The next model step end to end, on the CPU, unattended over hours and sessions: every stage
# skips what is already done, so re-running the same command goes on where it stopped.
#   1. training data: render rounds 0-7 of data/train128 (scripts/render_v2_data.sh train 8,
#      WORKERS=2: 576 scenes, about 245 an hour on an idle 2-core AMD EPYC with the fast
#      denoiser, so 2.4 hours from none). v17a's scenes are rounds 0-6 and round 7's first
#      23 family seeds (10420-10442), so its subset exists only once round 7 is rendered;
#   2. generator v17a: scripts/train_generator_v17.sh (v16 + 3,500 steps of its recipe on
#      those 527 scenes, one thread, about 70 min) while one worker renders rounds 8-11;
#   3. v17a's checks beside the shipped pair (scripts/eval_generator.sh v17a ... ladder depth);
#   4. stage 2 v23 on v17a's renders of rounds 7-11 (scripts/train_stage2_v23.sh 2000);
#   5. the pair on the test ladder with v22 on the same reconstructions
#      (runs/eval_v17a_v23/ladder; pair it with runs/eval_v17a/ladder by
#      benchmarks/compare_ladders.py, and with the shipped pair's runs/raw_fill_v16).
# Logs: logs/next_models_*.log. Nothing is shipped: that takes the evaluation and a decision.
#   nohup scripts/next_models.sh > logs/next_models.log 2>&1 &
set -euo pipefail
cd "$(dirname "$0")/.."
P=${PROSPLAT:-.venv/bin/prosplat}
mkdir -p logs
GEN=runs/gen_v17a/checkpoint.safetensors
say() { echo "[$(date +%H:%M)] next_models: $*"; }
say "1. rendering rounds 0-7"
nice -n 19 env WORKERS="${WORKERS:-2}" THREADS=1 scripts/render_v2_data.sh train 8 \
  >> logs/next_models_render.log 2>&1
say "2. generator v17a, rounds 8-11 rendering beside it"
nice -n 19 env WORKERS=1 THREADS=1 scripts/render_v2_data.sh train 12 \
  >> logs/next_models_render.log 2>&1 &
render=$!
if ! grep -q '"step": 3500' runs/gen_v17a/log.jsonl 2> /dev/null; then
  scripts/train_generator_v17.sh 3500 >> logs/next_models_v17a.log 2>&1
fi
say "3. v17a's checks"
[ -f runs/eval_v17a/ladder/ladder.json ] || scripts/eval_generator.sh v17a "$GEN" ladder
[ -f runs/eval_v17a/depth.log ] || scripts/eval_generator.sh v17a "$GEN" depth
wait "$render"
say "4. stage 2 v23"
scripts/train_stage2_v23.sh 2000 >> logs/next_models_v23.log 2>&1
say "5. the pair on the ladder"
[ -f runs/eval_v17a_v23/ladder/ladder.json ] || OMP_NUM_THREADS=2 $P eval ladder \
  --data data/test128 --sizes 64 128 --views 4 --rows paste generator enhanced fill \
  --generator "$GEN" --improve runs/s2v23/run/improve.safetensors \
  --compare-improve v22=prosplat/weights/improve_tiny.safetensors \
  --out runs/eval_v17a_v23/ladder > logs/next_models_ladder.log 2>&1
say "done"
