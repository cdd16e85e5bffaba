# Sourced by training scripts: a folder of links to the scenes of data/train128 whose seeds
# fall in the given ranges, so a run can be repeated on exactly the scenes it saw while the
# data set keeps growing (scripts/render_v2_data.sh train adds scenes in rounds).
#   scene_subset DEST "FIRST-LAST FIRST-LAST ..."   (a missing scene is an error)
# The links are made in a fresh folder first; DEST is left alone when it already holds
# exactly those links, so runs started side by side on one subset do not pull the scenes
# from under each other, and is otherwise replaced.
scene_subset() {
  local dest=$1 range first last seed found tmp
  tmp=$(mktemp -d "${dest%/}.new.XXXXXX")
  for range in $2; do
    first=${range%-*} last=${range#*-}
    for seed in $(seq "$first" "$last"); do
      found=$(train_scene "$seed") || {
        echo "scene_subset: no scene with seed $seed in data/train128" >&2
        rm -rf "$tmp"
        return 1
      }
      ln -s "$(realpath --relative-to="$dest" "$found")" "$tmp/$(basename "$found")"
    done
  done
  if [ -d "$dest" ] && diff -q <(_subset_links "$dest") <(_subset_links "$tmp") > /dev/null; then
    rm -rf "$tmp"
  else
    rm -rf "$dest" && mv -T "$tmp" "$dest"
  fi
}

# The folder of data/train128's scene with this seed (every folder name ends in its seed, and
# train seeds are unique across families and hard scenes); fails when there is none.
#   train_scene SEED
train_scene() {
  compgen -G "data/train128/*_$(printf %06d "$1")"
}

# name -> target, one line a link, sorted: what scene_subset compares.
_subset_links() {
  local link
  for link in "$1"/*; do printf '%s %s\n' "$(basename "$link")" "$(readlink "$link")"; done | sort
}

# The hard scenes of render rounds FIRST..N-1 (FIRST default 0), as seed ranges for
# scene_subset: seeds 20000 + 100 kind + 2 round (+1), six kinds.
#   hard_rounds N [FIRST]
hard_rounds() {
  local k first=${2:-0}
  for k in 0 1 2 3 4 5; do printf '20%d%02d-20%d%02d ' "$k" $((2 * first)) "$k" $((2 * $1 - 1)); done
}
