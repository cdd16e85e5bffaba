#!/usr/bin/env bash
# Train the generator on a lent GPU machine in bounded calls, resuming between them.
#
# The machine has its own torch (CUDA) and no network, so the call brings what it lacks:
#   .whl/   wheels: plyfile, gsplat (its CUDA kernels compile on first use, nvcc + ninja)
#   .gpu/   scene packs (`prosplat scenes pack`), and in the first call the LPIPS weights
# Everything it keeps between calls lives under /tmp (a warm machine keeps /tmp), so each call
# adds the packs it carries and resumes the run in /tmp/run; the weights and the log go to
# $OUT at the end of every call. Usage (from the repository root on the GPU machine):
#   scripts/gpu_train_generator.sh SECONDS NAME "OPTIONS" [NAME "OPTIONS" ...]
# Each NAME is a run in /tmp/runs/NAME with its `prosplat train generator` options; the runs
# share the GPU and train at once. SECONDS bounds this call; the runs are stopped then and
# resume next call from their last checkpoint (--save-every).
set -uo pipefail
budget=${1:?usage: gpu_train_generator.sh SECONDS NAME "OPTIONS" [NAME "OPTIONS" ...]}
shift
t0=$(date +%s)
python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade \
  --target /tmp/site .whl/*.whl || exit 1
export PYTHONPATH=/tmp/site:$PWD PROSPLAT_CACHE=/tmp/cache TORCH_EXTENSIONS_DIR=/tmp/torch_ext
export PYTHONUNBUFFERED=1 MAX_JOBS=16
mkdir -p /tmp/cache /tmp/data
cp -n .gpu/lpips_*.safetensors /tmp/cache/ 2>/dev/null
for f in .gpu/*.npz; do [ -e "$f" ] && cp -n "$f" /tmp/data/; done
ls -la /tmp/data
nvidia-smi --query-gpu=name,memory.used,memory.total --format=csv,noheader

# gsplat's kernels: compiled once per machine (cached under /tmp/torch_ext); a failure or a
# compile past GSPLAT_SECONDS leaves the CPU rasterizer (network on the GPU, splats on 16 cores)
if [ ! -e /tmp/gsplat_ok ] && [ ! -e /tmp/gsplat_failed ]; then
  if timeout "${GSPLAT_SECONDS:-300}" python3 - <<'EOF' > /tmp/gsplat_build.log 2>&1; then
import torch
from gsplat import rasterization
m = torch.zeros(1, 3, device="cuda"); m[0, 2] = 2
q = torch.tensor([[1.0, 0, 0, 0]], device="cuda")
s = torch.full((1, 3), 0.1, device="cuda")
o = torch.ones(1, device="cuda")
c = torch.ones(1, 1, 3, device="cuda")
K = torch.tensor([[[32.0, 0, 16], [0, 32, 16], [0, 0, 1]]], device="cuda")
img, alpha, _ = rasterization(m, q, s, o, c, torch.eye(4, device="cuda")[None], K, 32, 32, sh_degree=0)
print("gsplat ok", float(alpha.max()))
EOF
    touch /tmp/gsplat_ok
  else
    touch /tmp/gsplat_failed
  fi
  tail -5 /tmp/gsplat_build.log
fi
if [ -e /tmp/gsplat_failed ]; then
  # keep the CPU path: hide gsplat so prosplat.render does not pick it
  rm -rf /tmp/site/gsplat
fi
echo "setup took $(( $(date +%s) - t0 )) s; gsplat: $(ls /tmp/gsplat_ok /tmp/gsplat_failed 2>/dev/null)"

data=$(ls /tmp/data/train*.npz | paste -sd, -)
val=$(ls /tmp/data/val*.npz 2>/dev/null | head -1)
left=$(( budget - ($(date +%s) - t0) ))
names=()
while [ $# -ge 2 ]; do
  name=$1 opts=$2
  shift 2
  names+=("$name")
  # shellcheck disable=SC2086  # OPTIONS is a list of words
  timeout --signal=INT "$left" python3 -m prosplat train generator --device cuda --data "$data" \
    ${val:+--val "$val"} --out "/tmp/runs/$name" $opts > "/tmp/runs_$name.log" 2>&1 &
done
wait
for name in "${names[@]}"; do
  echo "== $name"
  grep -v "it/s\]" "/tmp/runs_$name.log" | tail -5
  tail -2 "/tmp/runs/$name/log.jsonl"
  cp "/tmp/runs/$name/checkpoint.safetensors" "$OUT/${name}_checkpoint.safetensors"
  cp "/tmp/runs/$name/log.jsonl" "$OUT/${name}_log.jsonl"
done
