# Sourced by the training scripts: weights as shipped at a commit, taken from git history
# (the files in the tree move on when newer weights ship).
#   shipped_before DEST FILE COMMIT   (FILE under prosplat/weights/; DEST is kept if present)
shipped_before() {
  [ -f "$1" ] && return 0
  mkdir -p "$(dirname "$1")"
  git show "$3:prosplat/weights/$2" > "$1.part$$" && mv "$1.part$$" "$1"  # $$: two scripts at once
}
