#!/usr/bin/env bash
# Stage 2 on a lent GPU machine in one bounded call: curate on its CPU cores, train on its GPU.
#
# The curated sets hold about 20 MB of float16 images per scene, far more than one call may
# carry (64 MiB with the working tree), so the call carries the scenes instead, as a depth-free pack
# (`prosplat scenes pack --no-depth`, ~0.15-0.17 MB a scene), and curates them there: SHARDS
# processes of one thread per set (`train curate --first/--count`), raw64 (2/3/4/6 inputs) and
# raw128 (2/4) as stage 2 v18's sets (prosplat.train.recipes), with the shipped generator and its
# depth sweep. Then `prosplat train improve --device cuda` from the shipped stage 2 with the
# options given, for as many steps as the time left allows: a short probe run measures the
# step time first, so the cosine schedule ends where the budget does.
#
# What the call carries (ignored folders, named in the call's carry):
#   .whl/  wheels the machine lacks: diffusers, importlib_metadata, plyfile (py3-none-any)
#   .gpu/  the scene pack(s) *.npz and lpips_alex_v0.1.f16.safetensors (LPIPS weights in
#          float16, 5 MB instead of 10, widened back to float32 there)
# SETS="NAME:VIEWS:SIZE:REFINE_STEPS ..." the curated sets (default raw64:2,3,4,6:64:0
#   raw128:2,4:128:0; e.g. add ref64:2,4:64:300 for renders refined as `prosplat.pipeline.refine` does).
# RATE=SECONDS: a step's time an earlier call printed ("probe: S s/step") skips the probe, whose
#   first step costs ~100 s on a fresh machine (paid again by the run itself); batch 16: 0.104.
# INIT= another stage 2 to start from (default: the shipped one; a file that travels too, or a
#   path on a warm machine: copy an earlier call's $W/s2_run/improve.safetensors first, since
#   each call starts its run anew).
# GENERATOR= the generator whose renders are curated (default: the shipped one; a candidate's
#   .safetensors travels in the carry, e.g. under .gpu/). A warm machine reuses the sets an
#   earlier call curated: give another WORK= when GENERATOR or SETS change between calls.
# What comes back in $OUT: improve.safetensors, log.jsonl, the curation and training logs (a
# training run stopped by the time limit still saves improve.safetensors at the step reached).
# Costs measured on a lent H200 (16 cores, 144 scenes, SHARDS=16, 2026-11-26): curating raw64
# (2/4 inputs), raw128 (4), ref64 (2/4, 100 steps) and ref128 (4, 100 steps) took 298 s, the
# ref128 shards alone about 3.5 min for 9 scenes each, leaving a 555-s call 135 s of training
# (0.104 s a step at batch 16). A second call reuses the curated sets only while the machine is
# still warm (30 s after the first returns): have its command ready, and leave room in the
# 64-MiB carry for the INIT file it brings.
# Usage (repository root, on the GPU machine):
#   scripts/gpu_train_stage2.sh SECONDS [prosplat train improve options ...]
# Dry run elsewhere: PY=.venv/bin/python DEVICE=cpu PACKS=a.npz SHARDS=2 MIN_STEPS=2 OUT=/tmp/o
# (WORK= another folder than /tmp for the sets, runs and logs).
set -uo pipefail
budget=${1:?usage: gpu_train_stage2.sh SECONDS [train improve options ...]}
shift
t0=$(date +%s)
left() { echo $((budget - ($(date +%s) - t0))); }
OUT=${OUT:-/tmp/out}
W=${WORK:-/tmp}  # what a warm machine keeps between calls: curated sets, runs, logs
PY=${PY:-python3}
DEVICE=${DEVICE:-cuda}
rm -rf "$W/s2_probe" "$W/s2_run"  # a second call trains anew (INIT= to go on from the first)
mkdir -p "$OUT" "$W/cache" "$W/s2_sets" "$W/s2_logs"
$PY -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade \
  --target "$W/site" .whl/*.whl || exit 1
export PYTHONPATH=$W/site:$PWD PROSPLAT_CACHE=$W/cache PYTHONUNBUFFERED=1
$PY scripts/gpu_lpips.py unpack .gpu || exit 1
$PY - <<'EOF' || exit 1
import os
from prosplat.render.native import load  # build the rasterizer once, not per shard
load()
import torch
gpu = torch.cuda.get_device_name() if torch.cuda.is_available() else "no GPU"
print("torch", torch.__version__, gpu, "cores", os.cpu_count())
EOF
packs=$(ls ${PACKS:-.gpu/*.npz} | paste -sd, -)
n=$($PY -c "from prosplat.data.dataset import scene_sources as s; print(len(s('$packs'.split(','))))")
shards=${SHARDS:-8}
per=$(((n + shards - 1) / shards))
echo "setup $(($(date +%s) - t0)) s; $n scenes in $packs, $shards shards of $per per set"
# SETS: NAME:VIEWS:SIZE:REFINE_STEPS for each curated set (refined sets take ~10x longer)
SETS=${SETS:-raw64:2,3,4,6:64:0 raw128:2,4:128:0}
for k in $(seq 0 $((shards - 1))); do
  for spec in $SETS; do
    IFS=: read -r name views size refine <<< "$spec"
    [ -f "$W/s2_sets/${name}_$k.safetensors" ] && continue  # a warm machine's earlier call
    OMP_NUM_THREADS=1 $PY -m prosplat train curate --data "$packs" --views "$views" \
      ${GENERATOR:+--generator "$GENERATOR"} --size "$size" --generator-size 128 \
      --refine-steps "$refine" --first $((k * per)) --count "$per" \
      --out "$W/s2_sets/${name}_$k.safetensors" \
      > "$W/s2_logs/curate_${name}_$k.log" 2>&1 &
  done
done
wait
sets=$(for spec in $SETS; do ls "$W/s2_sets/${spec%%:*}"_*.safetensors; done | paste -sd, -)
echo "curated $(ls "$W/s2_sets" | wc -l) files by $(($(date +%s) - t0)) s"
tail -c 300 "$(ls "$W"/s2_logs/curate_*.log | head -1)"
failed=$(grep -L "curated set" "$W"/s2_logs/curate_*.log)
[ -z "$failed" ] || echo "failed curations: $failed"

init=${INIT:-prosplat/weights/improve_tiny.safetensors}  # the stage 2 to start from
rate=${RATE:-}
if [ -z "$rate" ]; then
  # the probe: 60 steps with the same options, timed between steps 20 and 60
  $PY -m prosplat train improve --device "$DEVICE" --data "$sets" --out "$W/s2_probe" --init "$init" \
    --steps 60 --log-every 20 --save-every 60 "$@" > "$W/s2_logs/probe.log" 2>&1
  rate=$($PY - "$W/s2_probe/log.jsonl" <<'EOF'
import json, sys
recs = [json.loads(line) for line in open(sys.argv[1]) if '"seconds"' in line]
(a, b) = (recs[0], recs[-1])
print((b["seconds"] - a["seconds"]) / (b["step"] - a["step"]))
EOF
)
fi
[ -n "$rate" ] || { tail -c 2000 "$W/s2_logs/probe.log"; exit 1; }
warm=$([ -n "${RATE:-}" ] && echo 110 || echo 0)  # the run's own slow first step, which a probe paid
steps=$($PY -c "print(max(${MIN_STEPS:-100}, int(0.85 * ($(left) - 45 - $warm) / $rate) // 100 * 100))")
echo "probe: $rate s/step; training $steps steps with $(left) s left"
limit=$(($(left) - 20))
[ "$limit" -gt 60 ] || limit=60
timeout --signal=INT "$limit" $PY -m prosplat train improve --device "$DEVICE" \
  --data "$sets" --out "$W/s2_run" --init "$init" --steps "$steps" --save-every 500 --log-every 50 "$@" \
  > "$W/s2_logs/train.log" 2>&1
echo "training exit $? at $(($(date +%s) - t0)) s"
grep -v "it/s\]" "$W/s2_logs/train.log" | tail -5
tail -3 "$W/s2_run/log.jsonl"
cp "$W/s2_run/improve.safetensors" "$W/s2_run/log.jsonl" "$OUT/" 2>/dev/null
tar czf "$OUT/logs.tgz" -C "$W" s2_logs
ls -la "$OUT"
