#!/usr/bin/env bash
# Train the generator on a lent GPU machine in one bounded call; several runs share the GPU.
#
# The machine has its own torch (CUDA) and no network; scripts/gpu_generator_prepare.sh makes
# what the call carries, .gpu_gen/ (name it in the call's carry):
#   whl/         gsplat (its CUDA kernels compile there on first use, ~75 s, with ninja) and the
#                pure-Python packages the machine lacks
#   lpips_*.f16.safetensors  the LPIPS weights in float16, widened there (scripts/gpu_lpips.py)
#   train_*.npz  the scenes with depth (`prosplat scenes pack`)
# Usage (repository root, on the GPU machine):
#   scripts/gpu_train_generator.sh SECONDS NAME "OPTIONS" [NAME "OPTIONS" ...]
# Each NAME is a run in $WORK/runs/NAME with its `prosplat train generator` options (without
# --steps); the runs train at once. A probe first runs every run PROBE_STEPS steps together
# and times them, so each run's cosine schedule ends where the call's SECONDS do; then the runs
# train for that many steps, sent SIGINT if they overrun the call (train generator saves the
# step reached). A warm machine's earlier run in $WORK/runs/NAME is resumed: its
# steps are added. What comes back in $OUT: NAME_checkpoint.safetensors, NAME_log.jsonl and
# logs.tgz (setup, gsplat build, probe and training logs).
# gsplat renders every camera of a scene in one call (prosplat.render.gsplat_backend); without
# it (a failed build) the renders go to the CPU rasterizer on the machine's cores.
# RATE=SECONDS: the step time an earlier call printed for the same runs ("probe: S s a step");
# it skips the probe, whose first step took 95-125 s on an H200 (2026-11-29; the runs' own
# first steps after it 2 s). Two runs of batch 4 at 64/128 px: RATE=0.5.
# Dry run elsewhere: PY=.venv/bin/python DEVICE=cpu GSPLAT=0 WORK=/tmp/g OUT=/tmp/o.
set -uo pipefail
budget=${1:?usage: gpu_train_generator.sh SECONDS NAME "OPTIONS" [NAME "OPTIONS" ...]}
shift
t0=$(date +%s)
left() { echo $((budget - ($(date +%s) - t0))); }
G=${CARRY:-.gpu_gen}
W=${WORK:-/tmp}
OUT=${OUT:-/tmp/out}
PY=${PY:-python3}
DEVICE=${DEVICE:-cuda}
mkdir -p "$OUT" "$W/cache" "$W/runs" "$W/logs"
$PY -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade \
  --target "$W/site" "$G"/whl/*.whl || exit 1
export PYTHONPATH=$W/site:$PWD PROSPLAT_CACHE=$W/cache TORCH_EXTENSIONS_DIR=$W/torch_ext
export PYTHONUNBUFFERED=1 MAX_JOBS=16
$PY scripts/gpu_lpips.py unpack "$G" || exit 1
command -v nvidia-smi > /dev/null && nvidia-smi --query-gpu=name,memory.total --format=csv,noheader

# gsplat's kernels: compiled once per machine (cached in $W/torch_ext); a failure or a compile
# past GSPLAT_SECONDS leaves the CPU rasterizer
if [ "${GSPLAT:-1}" = 1 ] && [ ! -e "$W/gsplat_ok" ] && [ ! -e "$W/gsplat_failed" ]; then
  if timeout "${GSPLAT_SECONDS:-240}" $PY - > "$W/logs/gsplat_build.log" 2>&1 <<'EOF'; then
import torch
from prosplat import Camera, Gaussians
from prosplat.render.gsplat_backend import render_gsplat_views
g = Gaussians(torch.zeros(1, 3), torch.tensor([[1.0, 0, 0, 0]]), torch.full((1, 3), 0.1),
              torch.ones(1), torch.ones(1, 1, 3)).to("cuda")
cam = Camera.look_at((0, 0, -2.0), (0, 0, 0), (0, -1, 0), 32.0, 32, 32)
rgb, alpha, depth = render_gsplat_views(g, [cam, cam], torch.zeros(3, device="cuda"))
print("gsplat ok", rgb.shape, float(alpha.max()), float(depth.max()))
EOF
    touch "$W/gsplat_ok"
  else
    touch "$W/gsplat_failed"
  fi
  tail -3 "$W/logs/gsplat_build.log"
fi
[ -e "$W/gsplat_ok" ] || rm -rf "$W/site/gsplat"  # the CPU path: prosplat.render finds no gsplat
echo "setup $(($(date +%s) - t0)) s; gsplat: $(ls "$W"/gsplat_* 2> /dev/null)"

data=$(ls "$G"/train_*.npz | paste -sd, -)
names=() options=()
while [ $# -ge 2 ]; do names+=("$1") options+=("$2") && shift 2; done
threads=$((${CORES:-16} / ${#names[@]}))
# job control: without it a script's background jobs ignore SIGINT, and the stop at the time
# limit (train generator's save on Ctrl-C) would never reach them
set -m
train() {  # NAME OUT OPTIONS... : one run, in the background
  local name=$1 out=$2
  shift 2
  OMP_NUM_THREADS=$threads $PY -m prosplat train generator --device "$DEVICE" --data "$data" \
    --out "$out" "$@" > "$W/logs/$(basename "$out").log" 2>&1 &
}
# the probe: every run PROBE_STEPS steps at once, timed from its second log record (step 10)
# on, after CUDA's warm-up. Its first step takes 1.5-2 min on an H200 (the runs' first steps
# after it take 2 s), so RATE=SECONDS (a step's time that an earlier call printed for the same
# runs) skips it.
probe=${PROBE_STEPS:-30}
rate=${RATE:-}
if [ -z "$rate" ]; then
  for i in "${!names[@]}"; do
    rm -rf "$W/probe_${names[$i]}"
    # shellcheck disable=SC2086  # OPTIONS is a list of words
    train "${names[$i]}" "$W/probe_${names[$i]}" ${options[$i]} --steps "$probe" --log-every 5 \
      --save-every 100000
  done
  wait
  rate=$($PY - "$W" "${names[@]}" <<'EOF'
import json, sys
rates = []
for name in sys.argv[2:]:
    recs = [json.loads(line) for line in open(f"{sys.argv[1]}/probe_{name}/log.jsonl")]
    a, b = recs[min(1, len(recs) - 2)], recs[-1]
    rates.append((b["seconds"] - a["seconds"]) / (b["step"] - a["step"]))
print(max(rates))
EOF
  )
fi
[ -n "$rate" ] || { tail -c 3000 "$W"/logs/probe_*.log; exit 1; }
steps=$($PY -c "print(max(${MIN_STEPS:-50}, int(0.9 * ($(left) - 40) / $rate) // 50 * 50))")
echo "probe: $rate s a step with ${#names[@]} runs; $steps steps each, $(left) s left"
for i in "${!names[@]}"; do
  run="$W/runs/${names[$i]}"
  done_=$($PY -c "from prosplat.train.common import weights_step as w; print(w('$run/checkpoint.safetensors') or 0)" 2> /dev/null || echo 0)
  # shellcheck disable=SC2086
  train "${names[$i]}" "$run" ${options[$i]} --steps $((done_ + steps)) --save-every 250 \
    --log-every 25
done
sleep 1
limit=$(($(left) - 15))
[ "$limit" -gt 30 ] || limit=30
# a stopper sends the runs SIGINT at the limit (each saves where it is); waited on are the runs
(sleep "$limit" && pkill -INT -f "prosplat train generator --device $DEVICE") > /dev/null 2>&1 &
stopper=$!
for job in $(jobs -p); do [ "$job" != "$stopper" ] && wait "$job"; done
kill -- -"$stopper" 2> /dev/null  # its process group (set -m), the sleep with it
wait "$stopper" 2> /dev/null
echo "training ended at $(($(date +%s) - t0)) s"
for name in "${names[@]}"; do
  echo "== $name"
  grep -v "it/s\]" "$W/logs/$name.log" | tail -3
  tail -2 "$W/runs/$name/log.jsonl"
  cp "$W/runs/$name/checkpoint.safetensors" "$OUT/${name}_checkpoint.safetensors"
  cp "$W/runs/$name/log.jsonl" "$OUT/${name}_log.jsonl"
done
tar czf "$OUT/logs.tgz" -C "$W" logs
ls -la "$OUT"
