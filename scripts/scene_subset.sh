# Sourced by training scripts: a folder of links to the scenes of data/train128 whose seeds
# fall in the given ranges, so a run can be repeated on exactly the scenes it saw while the
# data set keeps growing (scripts/render_v2_data.sh train adds scenes in rounds).
#   scene_subset DEST "FIRST-LAST FIRST-LAST ..."   (DEST is rebuilt; a missing scene is an error)
scene_subset() {
  local dest=$1 range first last seed found
  rm -rf "$dest" && mkdir -p "$dest"
  for range in $2; do
    first=${range%-*} last=${range#*-}
    for seed in $(seq "$first" "$last"); do
      found=$(compgen -G "data/train128/*_$(printf %06d "$seed")" || true)
      [ -n "$found" ] || { echo "scene_subset: no scene with seed $seed in data/train128" >&2; return 1; }
      ln -s "$(realpath --relative-to="$dest" "$found")" "$dest/$(basename "$found")"
    done
  done
}

# The hard scenes of render rounds 0..N-1, as seed ranges for scene_subset: seeds
# 20000 + 100 kind + 2 round (+1), six kinds.
#   hard_rounds N
hard_rounds() {
  local k
  for k in 0 1 2 3 4 5; do printf '20%d00-20%d%02d ' "$k" "$k" $((2 * $1 - 1)); done
}
