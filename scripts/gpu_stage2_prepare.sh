#!/usr/bin/env bash
# Make what scripts/gpu_train_stage2.sh carries to a lent GPU machine, here, before the call
# (the machine's time counts from its start, so nothing is prepared there):
#   .whl/  diffusers, importlib_metadata and plyfile wheels for the machine's Python 3.12
#          (pure Python, so no build there), at the versions this checkout's .venv uses
#   .gpu/  the LPIPS weights in float16 (the script widens them back) and the scenes as a
#          depth-free pack, .gpu/s2_000.npz (`prosplat scenes pack --no-depth`)
# Both folders go into .git/info/exclude, so the call carries them only when named in its
# carry: ["`.gpu`", "`.whl`"]. The pack is made again when SCENES changed.
# Prints the size the call will carry: tracked files + .gpu + .whl must stay under 64 MiB
# (about 200 scenes with today's 25 MiB tree).
#   [SCENES="FIRST-LAST ..."] scripts/gpu_stage2_prepare.sh
# SCENES: seed ranges of data/train128 (`prosplat scenes subset --seeds`; hard:A-B are the hard
# scenes of render rounds A-B), default v18's 160 scenes: "10000-10135 hard:0-1".
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PY:-.venv/bin/python}
P=${PROSPLAT:-.venv/bin/prosplat}
for d in .whl .gpu; do
  grep -qx "/$d/" .git/info/exclude 2> /dev/null || echo "/$d/" >> .git/info/exclude
done
mkdir -p .whl .gpu
version() { "$PY" -c "import importlib.metadata as m; print(m.version('$1'))"; }
"$PY" -m pip download -q --no-deps --only-binary=:all: --python-version 3.12 --implementation cp \
  --platform manylinux_2_28_x86_64 --platform manylinux2014_x86_64 -d .whl \
  "diffusers==$(version diffusers)" "importlib_metadata==$(version importlib_metadata)" \
  "plyfile==$(version plyfile)"
"$PY" scripts/gpu_lpips.py pack .gpu
"$P" scenes subset --data data/train128 --seeds "${SCENES:-10000-10135 hard:0-1}" \
  --out data/gpu_s2_scenes
# scenes subset leaves the folder (and its time) alone when the scenes are the same, so a pack
# newer than it holds these scenes; otherwise the old pack (made from data/ here) is replaced
if [ -e .gpu/s2_000.npz ] && [ .gpu/s2_000.npz -nt data/gpu_s2_scenes ]; then
  echo "keeping .gpu/s2_*.npz: it packs these scenes"
else
  rm -f .gpu/s2_*.npz
  "$P" scenes pack --data data/gpu_s2_scenes --out .gpu/s2 --no-depth --max-mb 60
fi
tree=$( (git ls-files -z; git ls-files -z --others --exclude-standard) | xargs -0 stat -c %s \
  | awk '{s += $1} END {print s}')
extra=$(du -cb .gpu .whl | tail -1 | cut -f1)
echo "the call carries $(((tree + extra) / 1048576)) MiB of 64 (tree $((tree / 1048576)), .gpu + .whl $((extra / 1048576)))"
