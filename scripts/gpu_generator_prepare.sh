#!/usr/bin/env bash
# Make what scripts/gpu_train_generator.sh carries to a lent GPU machine, here, before the call
# (the machine's time counts from its start, so nothing is prepared there), all in .gpu_gen/:
#   whl/   gsplat (its CUDA kernels compile there, with ninja) and the pure-Python packages it
#          and prosplat need that the machine's torch lacks, for its Python 3.12
#   lpips_alex_v0.1.f16.safetensors  the LPIPS weights in float16 (scripts/gpu_lpips.py)
#   train_*.npz  the scenes with depth, packed at JPEG q85 with 7-bit depth mantissas
#          (`prosplat scenes pack --jpeg-quality 85 --depth-bits 7`): about 0.13 MB a 16-view
#          128-px scene against 0.22 at q95 and full float16 (BENCHMARKS "Generator v11")
# .gpu_gen goes into .git/info/exclude: the call carries it only when named, carry [".gpu_gen"].
# Prints the size the call will carry: tracked files + .gpu_gen must stay under 64 MiB.
#   [DATA=data/gen_v6] [MAX_MB=17] scripts/gpu_generator_prepare.sh
# DATA: the scene folders to draw from (default: the shipped generator's 420 training scenes,
# generator-tiny's stages v6-v16 in prosplat.train.recipes, linked into data/gen_v6 from
# data/train128 by `prosplat scenes subset`), as many as fit MAX_MB of packs, spread evenly
# over the sorted names. The packs are made again when these change.
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PY:-.venv/bin/python}
P=${PROSPLAT:-.venv/bin/prosplat}
if [ -z "${DATA:-}" ]; then
  DATA=data/gen_v6
  "$P" scenes subset --data data/train128 --seeds "10000-10359 hard:0-4" --out "$DATA"
fi
MAX_MB=${MAX_MB:-17}
G=.gpu_gen
S=data/gpu_gen_scenes  # the subset, as links (data/ is ignored)
grep -qx "/$G/" .git/info/exclude 2> /dev/null || echo "/$G/" >> .git/info/exclude
mkdir -p "$G/whl"
version() { "$PY" -c "import importlib.metadata as m; print(m.version('$1'))"; }
"$PY" -m pip download -q --no-deps --only-binary=:all: --python-version 3.12 --implementation cp \
  --platform manylinux_2_28_x86_64 --platform manylinux2014_x86_64 -d "$G/whl" \
  gsplat==1.5.3 jaxtyping wadler_lindig ninja rich markdown-it-py mdurl pygments \
  "diffusers==$(version diffusers)" "importlib_metadata==$(version importlib_metadata)" \
  "plyfile==$(version plyfile)"
"$PY" scripts/gpu_lpips.py pack "$G"

# the subset: scenes spread evenly over DATA's sorted names (so each family keeps its share),
# as many as MAX_MB of packs holds at the size a sample of 8 of them packs to; as links
key="$DATA max $MAX_MB"
if [ "$(cat "$G/train.key" 2> /dev/null)" != "$key" ] || ! compgen -G "$G/train_*.npz" > /dev/null; then
  rm -rf "$G"/train_*.npz "$S"
  all=$(find -L "$DATA" -mindepth 2 -maxdepth 2 -name transforms.json -printf '%h\n' | sort)
  pick() {  # pick N: N names spread evenly over $all
    "$PY" -c "import sys; a = sys.stdin.read().split(); n = min(len(a), $1)
print('\n'.join(a[i * len(a) // n] for i in range(n)))" <<< "$all"
  }
  link() { mkdir -p "$1" && while read -r scene; do ln -s "$(realpath --relative-to="$1" "$scene")" "$1/"; done; }
  pick 8 | link "$S.sample"
  per=$("$P" scenes pack --data "$S.sample" --out "$G/probe" --jpeg-quality 85 --depth-bits 7 \
    --max-mb 100 | sed -n 's/.*: 8 scenes, \(.*\) MB/\1/p')
  rm -rf "$G"/probe_*.npz "$S.sample"
  pick "$("$PY" -c "print(int($MAX_MB * 0.95 / ($per / 8)))")" | link "$S"
  echo "$(ls "$S" | wc -l) of the $(wc -w <<< "$all") scenes of $DATA, ${per} MB per 8"
  "$P" scenes pack --data "$S" --out "$G/train" --jpeg-quality 85 --depth-bits 7 --max-mb "$MAX_MB"
  echo "$key" > "$G/train.key"
fi
tree=$( (git ls-files -z; git ls-files -z --others --exclude-standard) | xargs -0 stat -c %s \
  | awk '{s += $1} END {print s}')
extra=$(du -cbL "$G"/whl "$G"/*.npz "$G"/*.safetensors | tail -1 | cut -f1)
echo "the call carries $(((tree + extra) / 1048576)) MiB of 64 (tree $((tree / 1048576)), $G $((extra / 1048576)))"
