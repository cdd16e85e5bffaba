#!/usr/bin/env bash
# Outside data for `prosplat eval posed`: real photos no ProSplat scene generator made.
#   data/outside/fox   instant-ngp's fox: 50 phone photos (1080x1920) of a mounted fox with
#                      an OpenCV-distorted camera; its transforms.json lists 67 frames, so
#                      pass --skip-missing. Licence: see instant-ngp's data/nerf/fox.
# Usage: scripts/outside_data.sh            (clones only that folder from GitHub), or
#        INSTANT_NGP=/path/to/instant-ngp scripts/outside_data.sh   (copies from a checkout)
# Then, e.g.:
#   .venv/bin/prosplat eval posed data/outside/fox --skip-missing --out out/fox --size 128 \
#       --num-inputs 4 --targets 16 --refine-steps 300
set -euo pipefail
cd "$(dirname "$0")/.."
dest=data/outside/fox
if [ -f $dest/transforms.json ]; then echo "$dest is there"; exit 0; fi
mkdir -p data/outside
src=${INSTANT_NGP:-}
if [ -z "$src" ]; then
  src=$(mktemp -d)/instant-ngp
  git clone --depth 1 --filter=blob:none --sparse https://github.com/NVlabs/instant-ngp "$src"
  git -C "$src" sparse-checkout set data/nerf/fox
fi
cp -r "$src/data/nerf/fox" $dest
echo "wrote $dest ($(ls $dest/images | wc -l) images)"
