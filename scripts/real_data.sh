#!/usr/bin/env bash
# Real posed photo sets for `prosplat eval posed` (issue 68, item 1): photographs no ProSplat
# scene generator made, each fetched from a public GitHub repository (the images are in git,
# not LFS) at a pinned commit and prepared into data/real/<name>/ as a folder `eval posed`
# accepts: a transforms.json, or a COLMAP model in sparse/0 beside images/.
#
#   name        kind                          source (repo @ commit: path)                        poses
#   fox         object, hand-held phone       NVlabs/instant-ngp: data/nerf/fox                   transforms.json (as shipped)
#   flower      forward-facing plant (phone)  sabinleee/REAL: data/flower                         COLMAP binary (as shipped)
#   room        forward-facing indoor         sabinleee/REAL: data/room                           COLMAP binary (as shipped)
#   dtu_scan24  object on a table (DTU)       wqrray/nerf_baseline: data/dtu_scan24               NeuS cameras_sphere.npz -> COLMAP text
#   temple      object ring (Middlebury)      ma-mehralian/EKFPnP_matlab_toolbox: data/templeRing templeR_par.txt (K,R,t) -> COLMAP text
#   dino        object hemisphere (Middlebury) ma-mehralian/EKFPnP_matlab_toolbox: data/dino     dino_par.txt (K,R,t) -> COLMAP text
#   castle      outdoor facade (Strecha)      openMVG/SfM_quality_evaluation: .../castle-P30      gt_dense_cameras/*.camera -> COLMAP text
#   fountain    outdoor facade (Strecha)      openMVG/SfM_quality_evaluation: .../fountain-P11    gt_dense_cameras/*.camera -> COLMAP text
#
# The converted poses are the sets' own calibrations, rewritten exactly (no re-estimation);
# images are copied as they are (up to 3072x2048): `prosplat eval posed --size N` resizes them
# and their intrinsics together.
# Licences, as the repositories state them (keep data/ out of git, as .gitignore does):
#   fox: instant-ngp's NVIDIA Source Code License (non-commercial), no separate data licence;
#   flower, room: MIT (sabinleee/REAL, the author's own photos); dtu_scan24: MIT for the
#   repository's code, the DTU MVS data's own terms not stated; temple, dino: GPL-2 for the
#   toolbox, the Middlebury data credited (Seitz et al. 2006) without a licence; castle,
#   fountain: no licence file (Strecha et al., CVPR 2008, EPFL data). Treat all as research data.
#
# Usage:
#   scripts/real_data.sh                          fetch from GitHub (shallow, blob-filtered: only the set's files)
#   scripts/real_data.sh --from-mirror DIR        read local git mirrors instead (no network):
#                                                 DIR/<owner>+<name>/repo, DIR/<owner>+<name>,
#                                                 or DIR/<owner>/<name> (bare or work tree)
#   REAL_DATA_MIRROR=DIR scripts/real_data.sh     the same
#   scripts/real_data.sh [--from-mirror DIR] flower dino    only these sets
#   scripts/real_data.sh --list                   the set names, one a line
# A set whose folder is complete (data/real/<name>/.done) is skipped; delete the folder to redo it.
# Then every set, in one command (BENCHMARKS.md "Real photos: eight posed sets"):
#   for s in $(scripts/real_data.sh --list); do .venv/bin/prosplat eval posed data/real/$s \
#       --skip-missing --size 128 --num-inputs 4 --targets 4 --out runs/real/$s --overwrite; done
set -euo pipefail
cd "$(dirname "$0")/.."
root=$PWD
PY=${PYTHON:-$root/.venv/bin/python}
[ -x "$PY" ] || PY=python3

SETS="fox flower room dtu_scan24 temple dino castle fountain"
# name -> "owner/repo commit path"
src_of() {
  case $1 in
    fox) echo "NVlabs/instant-ngp abe236ee00cf90cfca6e36e65c00435d5b21f50a data/nerf/fox" ;;
    flower) echo "sabinleee/REAL c889c437571acef58a5348f13176746fc369bffb data/flower" ;;
    room) echo "sabinleee/REAL c889c437571acef58a5348f13176746fc369bffb data/room" ;;
    dtu_scan24) echo "wqrray/nerf_baseline eb0777530a09baf4451da3e3688ba5d7820d6e8d data/dtu_scan24" ;;
    temple) echo "ma-mehralian/EKFPnP_matlab_toolbox 77400fef0eabef17c2ffe46f77f83fb0e11c1076 data/templeRing" ;;
    dino) echo "ma-mehralian/EKFPnP_matlab_toolbox 77400fef0eabef17c2ffe46f77f83fb0e11c1076 data/dino" ;;
    castle) echo "openMVG/SfM_quality_evaluation 348a981ef51112e9848acfb20004f4ed6fbc6ce3 Benchmarking_Camera_Calibration_2008/castle-P30" ;;
    fountain) echo "openMVG/SfM_quality_evaluation 348a981ef51112e9848acfb20004f4ed6fbc6ce3 Benchmarking_Camera_Calibration_2008/fountain-P11" ;;
    *) echo "unknown set '$1' (known: $SETS)" >&2; return 1 ;;
  esac
}

mirror=${REAL_DATA_MIRROR:-}
only=()
while [ $# -gt 0 ]; do
  case $1 in
    --from-mirror) mirror=${2:?--from-mirror needs a folder}; shift 2 ;;
    --from-mirror=*) mirror=${1#*=}; shift ;;
    --list) for s in $SETS; do echo "$s"; done; exit 0 ;;
    -h|--help) sed -n '2,/^set -euo/p' "$0" | sed '$d; s/^# \{0,1\}//'; exit 0 ;;
    -*) echo "unknown option $1 (see --help)" >&2; exit 2 ;;
    *) src_of "$1" >/dev/null; only+=("$1"); shift ;;
  esac
done
[ ${#only[@]} -gt 0 ] && SETS="${only[*]}"
if [ -n "$mirror" ] && [ ! -d "$mirror" ]; then
  echo "error: --from-mirror $mirror is not a folder" >&2; exit 2
fi

tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT

# mirror_of OWNER/REPO -> a git dir or work tree under $mirror, or nothing
mirror_of() {
  local o=${1%%/*} n=${1#*/} c
  for c in "$mirror/$o+$n/repo" "$mirror/$o+$n" "$mirror/$o/$n" "$mirror/$n"; do
    if [ -d "$c" ] && git --git-dir="$c" rev-parse --git-dir >/dev/null 2>&1; then echo "$c"; return; fi
    if [ -d "$c/.git" ]; then echo "$c/.git"; return; fi
  done
}

# fetch_path OWNER/REPO COMMIT PATH OUT: the tree PATH at COMMIT, extracted under OUT/PATH
fetch_path() {
  local repo=$1 commit=$2 path=$3 out=$4 gd
  mkdir -p "$out"
  if [ -n "$mirror" ]; then
    gd=$(mirror_of "$repo")
    if [ -z "$gd" ]; then
      echo "error: no mirror of $repo under $mirror (looked for $mirror/${repo%%/*}+${repo#*/}/repo," \
        "$mirror/${repo%%/*}+${repo#*/}, $mirror/$repo)" >&2
      return 1
    fi
    # the pinned commit when the mirror has it, else its HEAD (said out loud)
    if ! git --git-dir="$gd" cat-file -e "$commit^{commit}" 2>/dev/null; then
      echo "  note: $gd lacks $commit; using its HEAD $(git --git-dir="$gd" rev-parse --short HEAD)" >&2
      commit=HEAD
    fi
    # file by file: a partial mirror may lack blobs the set does not need (database.db, ...)
    local meta f sha skipped=0
    while IFS= read -r -d '' line; do
      meta=${line%%$'\t'*} f=${line#*$'\t'} sha=${meta##* }
      if git --git-dir="$gd" cat-file -e "$sha" 2>/dev/null; then
        mkdir -p "$out/$(dirname "$f")"
        git --git-dir="$gd" cat-file blob "$sha" >"$out/$f"
      else
        skipped=$((skipped + 1))
      fi
    done < <(git --git-dir="$gd" ls-tree -r -z "$commit" -- "$path")
    [ $skipped -eq 0 ] || echo "  note: $skipped file(s) of $path are not in the mirror (skipped)"
    [ -d "$out/$path" ] || { echo "error: $path is not in $gd at $commit" >&2; return 1; }
    return 0
  fi
  local url=https://github.com/$repo clone=$tmp/clone-${repo//\//+}
  if [ ! -d "$clone" ]; then
    if ! timeout 60 git ls-remote "$url" HEAD >/dev/null 2>&1; then
      echo "error: cannot reach $url (no network, or GitHub is down)." >&2
      echo "       Use local mirrors instead: scripts/real_data.sh --from-mirror DIR" \
        "(or REAL_DATA_MIRROR=DIR)" >&2
      return 1
    fi
    git init -q "$clone"
    git -C "$clone" remote add origin "$url"
  fi
  # one commit, no blobs; then only the blobs under $path (checkout fetches them in a batch)
  git -C "$clone" fetch -q --depth 1 --filter=blob:none origin "$commit"
  git -C "$clone" checkout -q FETCH_HEAD -- "$path"
  mkdir -p "$out/$(dirname "$path")"
  cp -r "$clone/$path" "$out/$path"
}

# convert KIND SRC DEST: a COLMAP text model in DEST/sparse/0 from the set's own calibration
convert() {
  "$PY" - "$@" <<'EOF'
import json, math, sys
from pathlib import Path
import numpy as np

kind, src, dest = sys.argv[1], Path(sys.argv[2]), Path(sys.argv[3])

def quat(R):
    """Unit quaternion (w, x, y, z) of a rotation matrix, w >= 0 (COLMAP's convention)."""
    R = np.asarray(R, dtype=np.float64)
    U, _, Vt = np.linalg.svd(R)  # re-orthonormalise: published matrices carry 6 digits
    R = U @ Vt
    tr = np.trace(R)
    if tr > 0:
        s = math.sqrt(tr + 1.0) * 2
        q = [0.25 * s, (R[2, 1] - R[1, 2]) / s, (R[0, 2] - R[2, 0]) / s, (R[1, 0] - R[0, 1]) / s]
    elif R[0, 0] > R[1, 1] and R[0, 0] > R[2, 2]:
        s = math.sqrt(1.0 + R[0, 0] - R[1, 1] - R[2, 2]) * 2
        q = [(R[2, 1] - R[1, 2]) / s, 0.25 * s, (R[0, 1] + R[1, 0]) / s, (R[0, 2] + R[2, 0]) / s]
    elif R[1, 1] > R[2, 2]:
        s = math.sqrt(1.0 + R[1, 1] - R[0, 0] - R[2, 2]) * 2
        q = [(R[0, 2] - R[2, 0]) / s, (R[0, 1] + R[1, 0]) / s, 0.25 * s, (R[1, 2] + R[2, 1]) / s]
    else:
        s = math.sqrt(1.0 + R[2, 2] - R[0, 0] - R[1, 1]) * 2
        q = [(R[1, 0] - R[0, 1]) / s, (R[0, 2] + R[2, 0]) / s, (R[1, 2] + R[2, 1]) / s, 0.25 * s]
    q = np.array(q)
    q /= np.linalg.norm(q)
    return q if q[0] >= 0 else -q

def image_size(path):
    from PIL import Image
    with Image.open(path) as im:
        return im.size

def rq(M):
    """M = K R with K upper triangular, positive diagonal, R a rotation."""
    P = np.flipud(np.eye(3))
    Q, U = np.linalg.qr((P @ M).T)
    K = P @ U.T @ P
    R = P @ Q.T
    D = np.diag(np.sign(np.diag(K)))
    K, R = K @ D, D @ R
    if np.linalg.det(R) < 0:
        R = -R
    return K / K[2, 2], R

views = []  # (image name, K 3x3, R world->camera, t, width, height)
images = dest / "images"
if kind == "middlebury":
    par = next(src.glob("*_par.txt"))
    lines = par.read_text().split("\n")
    for line in lines[1:]:
        v = line.split()
        if len(v) != 22 or not (images / v[0]).is_file():
            continue  # the par file lists every view of the full set; keep those shipped
        nums = np.array(v[1:], dtype=np.float64)
        K, R, t = nums[:9].reshape(3, 3), nums[9:18].reshape(3, 3), nums[18:21]
        views.append((v[0], K, R, t, *image_size(images / v[0])))
elif kind == "strecha":
    for cam in sorted((src / "gt_dense_cameras").glob("*.camera")):
        name = cam.name[: -len(".camera")]
        if not (images / name).is_file():
            continue
        nums = np.array(cam.read_text().split(), dtype=np.float64)
        K, Rc2w, C = nums[:9].reshape(3, 3), nums[12:21].reshape(3, 3), nums[21:24]
        w, h = int(nums[24]), int(nums[25])
        R = Rc2w.T  # Strecha: x = K R^T (X - C)
        views.append((name, K, R, -R @ C, w, h))
elif kind == "neus":
    cams = np.load(src / "cameras_sphere.npz")
    names = sorted(p.name for p in images.iterdir())
    for i, name in enumerate(names):
        if f"world_mat_{i}" not in cams:
            break
        # world_mat @ scale_mat: the projection in NeuS's normalised frame (object in the unit sphere)
        P = (cams[f"world_mat_{i}"] @ cams[f"scale_mat_{i}"])[:3, :4]
        K, R = rq(P[:, :3])
        C = -np.linalg.solve(P[:, :3], P[:, 3])  # the camera centre; P's scale cancels
        t = -R @ C
        views.append((name, K, R, t, *image_size(images / name)))
else:
    raise SystemExit(f"unknown kind {kind}")
if not views:
    raise SystemExit(f"{src}: no posed images found")

model = dest / "sparse" / "0"
model.mkdir(parents=True, exist_ok=True)
cam_lines, img_lines = [], []
for i, (name, K, R, t, w, h) in enumerate(views, start=1):
    cam_lines.append(f"{i} PINHOLE {w} {h} {K[0,0]!r} {K[1,1]!r} {K[0,2]!r} {K[1,2]!r}")
    q = quat(R)
    img_lines.append(
        f"{i} {' '.join(repr(float(x)) for x in q)} {' '.join(repr(float(x)) for x in t)} {i} {name}"
    )
    img_lines.append("")  # no 2D points
(model / "cameras.txt").write_text(
    "# Camera list with one line of data per camera:\n"
    "#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]\n" + "\n".join(cam_lines) + "\n"
)
(model / "images.txt").write_text(
    "# Image list with two lines of data per image:\n"
    "#   IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME\n"
    "#   POINTS2D[] as (X, Y, POINT3D_ID)\n" + "\n".join(img_lines) + "\n"
)
(model / "points3D.txt").write_text("# no points: converted from the set's calibration\n")
# a sanity line: do the cameras look at a common point? (rings and facades should)
C = np.array([-R.T @ t for _, _, R, t, _, _ in views])
F = np.array([R[2] for _, _, R, _, _, _ in views])  # optical axes in the world
A = sum(np.eye(3) - np.outer(f, f) for f in F)
b = sum((np.eye(3) - np.outer(f, f)) @ c for f, c in zip(F, C))
X = np.linalg.lstsq(A, b, rcond=None)[0]
ahead = np.mean([(X - c) @ f > 0 for c, f in zip(C, F)])
print(f"  {len(views)} views; the optical axes meet nearest {np.round(X, 3)}, "
      f"in front of {ahead:.0%} of the cameras")
EOF
}

prepare() {
  local name=$1 dest=data/real/$1 repo commit path stage
  read -r repo commit path <<<"$(src_of "$name")"
  if [ -f "$dest/.done" ]; then echo "$dest is there"; return 0; fi
  echo "== $name: $repo@${commit:0:7} $path"
  stage=$tmp/$name
  rm -rf "$stage" "$dest"
  fetch_path "$repo" "$commit" "$path" "$stage" || return 1
  local s=$stage/$path
  mkdir -p "$dest"
  case $name in
    fox) cp -r "$s/." "$dest/" ;;
    flower|room) mkdir -p "$dest/sparse" && cp -r "$s/images" "$dest/images" && cp -r "$s/sparse/0" "$dest/sparse/0" ;;
    dtu_scan24) cp -r "$s/images" "$dest/images" && cp "$s/cameras_sphere.npz" "$dest/" && convert neus "$s" "$dest" ;;
    temple|dino) mkdir -p "$dest/images" && cp "$s"/*.png "$dest/images/" && cp "$s"/*.txt "$dest/" && convert middlebury "$s" "$dest" ;;
    castle|fountain) mkdir -p "$dest/images" && cp "$s"/images/*.jpg "$dest/images/" && convert strecha "$s" "$dest" ;;
  esac || return 1
  local n
  n=$(find "$dest/images" -type f 2>/dev/null | wc -l)
  if [ "$n" -eq 0 ]; then echo "error: no images for $name" >&2; return 1; fi
  printf '%s %s %s\n' "$repo" "$commit" "$path" >"$dest/SOURCE"
  touch "$dest/.done"
  echo "  wrote $dest ($(ls "$dest/images" | wc -l) images, $(du -sh "$dest" | cut -f1))"
}

mkdir -p data/real
fail=0
for s in $SETS; do prepare "$s" || { echo "error: $s failed" >&2; rm -rf "data/real/$s"; fail=1; }; done
exit $fail
