"""The user's own posed images, made ready for the generator.

:func:`load_posed_set` reads a ``transforms.json`` (nerfstudio, instant-ngp, NeRF synthetic;
lens distortion allowed) or a COLMAP model (text or binary, with its sparse points) and finds
each frame's image (a frame that lists an image already listed is left out: one image is one
view). :func:`pick_views` chooses the inputs (farthest-point sampling of camera centres, or
names / indices; coincident cameras count as one view, see
:func:`prosplat.geometry.view_choice.distinct_views`). :func:`load_views` turns frames into what the generator eats:
each image is read, RGBA composited over a background, undistorted onto a pinhole camera
(:mod:`prosplat.convert.distortion`) and resized to the model resolution with its intrinsics
scaled to match. :func:`near_far_from_points` gives the depth range from COLMAP's points.
"""

from __future__ import annotations

import json
import os
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F
from torch import Tensor

from prosplat.convert.colmap import read_colmap_model
from prosplat.convert.distortion import Distortion, undistort_image, undistorted_camera
from prosplat.convert.nerfstudio import TRANSFORMS_NAME, read_transforms
from prosplat.convert.posed import colmap_image_dirs, find_image
from prosplat.core.camera import Camera
from prosplat.core.image_io import composite, read_image_rgba
from prosplat.data.rigs import farthest_point_sampling
from prosplat.geometry.view_choice import first_of_pose
from prosplat.poses.frame import FAR_MARGIN, NEAR_MARGIN, near_far

__all__ = [
    "FAR_MARGIN",
    "NEAR_MARGIN",
    "PosedSet",
    "PosedView",
    "holds_poses",
    "load_posed_set",
    "load_views",
    "model_size",
    "near_far_from_points",
    "parse_background",
    "pick_views",
    "resolve_background",
    "view_camera",
]

MAX_INPUTS = 6  # the generator's cross-view attention takes at most this many views
_COLMAP_NAMES = ("cameras.txt", "images.txt", "cameras.bin", "images.bin")


@dataclass(frozen=True)
class PosedView:
    """One frame: display ``name``, ``image`` file, ``camera`` as the file gives it (the
    distorted image's intrinsics) and its lens (None: an ideal pinhole)."""

    name: str
    image: Path
    camera: Camera
    distortion: Distortion | None = None


@dataclass
class PosedSet:
    """Posed frames from one file. ``kind`` is "transforms", "colmap text" or "colmap binary";
    ``points [P,3]`` and ``observed`` (view name -> indices into points) come from COLMAP
    models (empty otherwise); ``nerf_synthetic`` is True for a transforms file that gives the
    field of view as ``camera_angle_x`` (the NeRF-synthetic form)."""

    views: list[PosedView]
    source: Path
    kind: str
    points: Tensor = field(default_factory=lambda: torch.zeros(0, 3, dtype=torch.float64))
    observed: dict[str, Tensor] = field(default_factory=dict)
    nerf_synthetic: bool = False
    #: depth bounds the file gives: view name -> (near, far) from per-frame ``near``/``far``,
    #: or the top-level pair under the key None (ProSplat's own scene folders write both)
    bounds: dict[str | None, tuple[float, float]] = field(default_factory=dict)
    #: frames left out because their image file is missing (``skip_missing=True``)
    missing: list[str] = field(default_factory=list)
    #: image paths as the file gives them, one per frame left out because an earlier frame
    #: lists the same image (a frame listed twice is one view, not two)
    repeats: list[str] = field(default_factory=list)

    def file_near_far(self, indices: Sequence[int]) -> tuple[float, float] | None:
        """The file's depth range for these views (per-frame bounds, else the top-level
        pair), or None when it gives none."""
        per = [self.bounds.get(self.views[i].name) for i in indices]
        if all(b is not None for b in per) and per:
            return min(b[0] for b in per), max(b[1] for b in per)
        return self.bounds.get(None)

    @property
    def names(self) -> list[str]:
        return [v.name for v in self.views]

    def first_of_pose(self) -> list[int]:
        """For each frame, the first frame with the same camera pose (itself if none earlier):
        :func:`prosplat.geometry.view_choice.first_of_pose` on the frames' cameras."""
        centers = torch.stack([v.camera.center.double() for v in self.views])
        forwards = torch.stack([v.camera.forward.double() for v in self.views])
        return first_of_pose(centers, forwards)


def _colmap_folder(path: Path) -> Path | None:
    folder = path if path.is_dir() else path.parent
    for sub in ("", "sparse/0", "sparse", "colmap/sparse/0"):
        d = folder / sub if sub else folder
        has_txt = (d / "cameras.txt").is_file() and (d / "images.txt").is_file()
        has_bin = (d / "cameras.bin").is_file() and (d / "images.bin").is_file()
        if has_txt or has_bin:
            return d
    return None


def holds_poses(path: str | Path) -> bool:
    """True when :func:`load_posed_set` finds poses at ``path``: a ``.json`` file, or a
    folder (or a file's folder) holding ``transforms.json`` or a COLMAP model. ``prosplat
    reconstruct`` poses a folder of photos itself when this is False."""
    path = Path(path)
    if path.suffix.lower() == ".json":
        return path.is_file()
    has_transforms = path.is_dir() and (path / TRANSFORMS_NAME).is_file()
    return has_transforms or _colmap_folder(path) is not None


def _unique_names(names: list[str]) -> list[str]:
    """File stems as display names; full relative paths where stems collide."""
    stems = [Path(n).stem for n in names]
    if len(set(stems)) == len(stems):
        return stems
    return [n.replace("/", "_").replace("\\", "_") for n in names]


def _bounds(d: dict) -> tuple[float, float] | None:
    """(near, far) when ``d`` holds a valid pair of numbers, else None."""
    near, far = d.get("near"), d.get("far")
    ok = all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in (near, far))
    return (float(near), float(far)) if ok and 0 < near < far < float("inf") else None


def _drop_repeats(items: list, key) -> tuple[list, list]:
    """``items`` without those whose image ``key(item)`` an earlier item already has, and the
    items left out, in order."""
    seen: set = set()
    kept, dropped = [], []
    for item in items:
        k = key(item)
        (dropped if k in seen else kept).append(item)
        seen.add(k)
    return kept, dropped


def _missing_error(missing: list[tuple[str, str]], total: int, where: str) -> FileNotFoundError:
    """The error for frames without an image: the first one, how many, and the ways out."""
    image, name = missing[0]
    more = f" ({len(missing)} of {total} frames have no image)" if len(missing) > 1 else ""
    return FileNotFoundError(
        f"image {image} of frame {name} in {where} is missing{more}; fix the file paths, pass "
        "--images DIR, or --skip-missing to leave out the frames without images"
    )


def load_posed_set(
    path: str | Path, images_dir: str | Path | None = None, skip_missing: bool = False
) -> PosedSet:
    """Read posed frames from a transforms file or a COLMAP model and find their images.

    Args:
        path: ``transforms*.json``, a folder holding ``transforms.json``, or a COLMAP model
            (its folder, or a project folder with ``sparse/0``), text or binary.
        images_dir: where the images are, if not where the format says (COLMAP: ``images/``
            beside ``sparse/``; transforms: relative to the json).
        skip_missing: leave out frames whose image file is missing (named in
            :attr:`PosedSet.missing`) instead of raising. Published sets do this: instant-ngp's
            fox ``transforms.json`` lists 67 frames for the 50 images in its folder. Off by
            default, because a wrong ``--images`` folder or a typo would otherwise silently
            shrink the set. With every image missing it still raises.

    A frame whose image an earlier frame already lists (the same file, however the path is
    spelled) is left out and named in :attr:`PosedSet.repeats`: one image is one view.

    Raises:
        FileNotFoundError: nothing readable at ``path``, or a frame's image is missing (every
            frame's, with ``skip_missing``).
        ValueError: a malformed file (the message names the line or frame), no frames.
    """

    path = Path(path)
    images_dir = Path(images_dir) if images_dir else None
    if not path.exists():
        raise FileNotFoundError(
            f"{path} does not exist; give a transforms.json or a COLMAP model folder"
        )
    model_dir = None if path.suffix.lower() == ".json" else _colmap_folder(path)
    if model_dir is not None:
        model = read_colmap_model(model_dir)
        dirs = colmap_image_dirs(model_dir, images_dir)
        images, repeated = _drop_repeats(model.images, lambda im: im.name)
        repeats = [im.name for im in repeated]
        names = _unique_names([im.name for im in images])
        views, missing = [], []
        for im, name in zip(images, names, strict=True):
            found = next((d / im.name for d in dirs if (d / im.name).is_file()), None)
            if found is None:
                missing.append((im.name, name))
                continue
            views.append(PosedView(name, found, im.camera, im.distortion))
        if missing and (not skip_missing or not views):
            where = f"the COLMAP model {model_dir} (looked in {', '.join(map(str, dirs[:3]))})"
            raise _missing_error(missing, len(names), where)
        left_out = {name for _, name in missing}
        observed = {
            n: model.observed[im.name]
            for im, n in zip(images, names, strict=True)
            if n not in left_out
        }
        kind = "colmap binary" if model.binary else "colmap text"
        posed = PosedSet(views, model_dir, kind, model.points, observed)
    else:
        json_path = path / TRANSFORMS_NAME if path.is_dir() else path
        if not json_path.is_file():
            raise FileNotFoundError(
                f"{path} holds neither {TRANSFORMS_NAME} nor a COLMAP model "
                f"({', '.join(_COLMAP_NAMES)})"
            )
        tf = read_transforms(json_path, allow_distortion=True)
        root = images_dir if images_dir is not None else json_path.parent

        def image_of(f) -> str:  # the same file however the path is spelled
            return str(find_image(root, f.file_path) or os.path.normpath(root / f.file_path))

        frames, repeated = _drop_repeats(tf.frames, image_of)
        repeats = [f.file_path for f in repeated]
        names = _unique_names([f.file_path for f in frames])
        views, missing = [], []
        for f, name in zip(frames, names, strict=True):
            found = find_image(root, f.file_path)
            if found is None:
                missing.append((str(root / f.file_path), name))
                continue
            views.append(PosedView(name, found, f.camera, f.distortion))
        if missing and (not skip_missing or not views):
            raise _missing_error(missing, len(names), str(json_path))
        top = json.loads(json_path.read_text())
        synthetic = "camera_angle_x" in top and "fl_x" not in top
        bounds = {None: _bounds(tf.meta)} if _bounds(tf.meta) else {}
        for f, name in zip(frames, names, strict=True):
            if _bounds(f.extra):
                bounds[name] = _bounds(f.extra)
        posed = PosedSet(views, json_path, "transforms", nerf_synthetic=synthetic, bounds=bounds)
    if not posed.views:
        raise ValueError(f"{path} has no frames (no registered images); nothing to reconstruct")
    posed.missing = [name for _, name in missing]
    posed.repeats = repeats
    return posed


def pick_views(posed: PosedSet, spec: Sequence[str] | None = None, count: int = 4) -> list[int]:
    """Indices of the input views: ``spec`` names or indices (in the file's order), or ``count``
    views by farthest-point sampling of the camera centres (from the first frame). Frames
    whose cameras coincide (:func:`~prosplat.geometry.view_choice.first_of_pose`) count as
    one view, the first of them: a second image from one pose adds no baseline.

    Raises:
        ValueError: an unknown name or index, a frame named twice or two named frames with one
            pose, a count outside 2-6 (the generator takes 2 to :data:`MAX_INPUTS` views) or
            above the distinct poses available, fewer than 2 distinct poses.
    """

    n = len(posed.views)
    names = posed.names
    if spec:
        out = []
        for s in spec:
            if s in names:
                out.append(names.index(s))
            elif s.lstrip("-").isdigit() and -n <= int(s) < n:
                out.append(int(s) % n)
            else:
                shown = ", ".join(names[:6]) + (" ..." if n > 6 else "")
                raise ValueError(
                    f"--inputs: no frame named {s!r} and no index 0-{n - 1}; frames: {shown}"
                )
        if len(set(out)) != len(out):
            raise ValueError(f"--inputs names a frame twice: {list(spec)}")
        count = len(out)
    if not 2 <= count <= MAX_INPUTS:
        raise ValueError(f"the generator takes 2-{MAX_INPUTS} input views, got {count}")
    first = posed.first_of_pose()
    distinct = [i for i in range(n) if first[i] == i]
    if len(distinct) < 2:
        raise ValueError(_too_few_poses(posed, len(distinct)))
    if spec:
        for k, i in enumerate(out):
            same = [j for j in out[:k] if first[j] == first[i]]
            if same:
                raise ValueError(
                    f"--inputs {names[same[0]]} and {names[i]} have the same camera pose; "
                    "choose views taken from different positions or directions"
                )
        return out
    if count > len(distinct):
        if len(distinct) == n:
            raise ValueError(f"{posed.source} has {n} frames; cannot pick {count} input views")
        raise ValueError(
            f"{posed.source} has {n} frames but only {len(distinct)} distinct camera poses "
            f"({n - len(distinct)} repeat the pose of an earlier frame); cannot pick {count} "
            f"input views: pick {len(distinct)} or fewer"
        )
    centers = torch.stack([posed.views[i].camera.center.double() for i in distinct])
    picked = farthest_point_sampling(centers, count)
    return sorted(distinct[k] for k in picked)


def _too_few_poses(posed: PosedSet, distinct: int) -> str:
    """Why ``posed`` cannot be reconstructed (fewer than 2 distinct camera poses), and what to
    do: one sentence for the command line."""
    n = len(posed.views)
    first = posed.repeats[0] if posed.repeats else ""
    listed = f"{first} {1 + posed.repeats.count(first)} times" if first else ""
    if n > distinct:
        also = f"; {len(posed.repeats)} more list an image again ({listed})" if first else ""
        what = (
            f"has {n} frames but they all have the same camera pose{also}; reconstruction "
            "needs at least 2 views from different positions or directions: give each frame "
            "its own camera pose (were the poses copied from one frame?)"
        )
    else:
        has = f"lists only {n} distinct image ({listed})" if first else f"has only {n} frame"
        what = (
            f"{has}; reconstruction needs at least 2 input views from different camera poses: "
            "list the images of more views"
        )
    return f"{posed.source} {what}"


def parse_background(text: str) -> Tensor:
    """``white``, ``black`` or ``R,G,B`` (0-1 floats or 0-255 integers) -> [3] in [0, 1]."""
    named = {"white": [1.0, 1.0, 1.0], "black": [0.0, 0.0, 0.0]}
    if text.lower() in named:
        return torch.tensor(named[text.lower()])
    try:
        vals = [float(x) for x in text.split(",")]
    except ValueError:
        vals = []
    if len(vals) != 3 or not all(v == v for v in vals):
        raise ValueError(f"--background must be white, black or R,G,B; got {text!r}")
    if any(v > 1 for v in vals):
        vals = [v / 255 for v in vals]
    if not all(0 <= v <= 1 for v in vals):
        raise ValueError(f"--background values must be in 0-1 (or 0-255), got {text!r}")
    return torch.tensor(vals)


def _has_alpha(path: Path) -> bool:
    import OpenImageIO as oiio

    inp = oiio.ImageInput.open(str(path))
    if inp is None:
        raise ValueError(f"cannot read image {path}: {oiio.geterror()}")
    try:
        spec = inp.spec()
        return spec.alpha_channel >= 0 or spec.nchannels in (2, 4)
    finally:
        inp.close()


def resolve_background(posed: PosedSet, choice: str | None) -> tuple[Tensor, str]:
    """The background RGBA images are composited over, and a sentence saying why.

    ``choice`` (``--background``) wins; otherwise NeRF-synthetic data (a transforms file with
    ``camera_angle_x`` and RGBA images) gets white, its dataset's convention, and anything
    else black (what an RGBA image premultiplied by its alpha shows).
    """
    if choice:
        bg = parse_background(choice)
        return bg, f"{choice} (--background)"
    rgba = _has_alpha(posed.views[0].image)
    if rgba and posed.nerf_synthetic:
        return torch.ones(3), "white (NeRF-synthetic RGBA images: the dataset's convention)"
    if rgba:
        return torch.zeros(3), "black (RGBA images; choose another with --background)"
    return torch.zeros(3), "none needed (no alpha channel)"


def model_size(width: int, height: int, size: int) -> tuple[int, int]:
    """(W', H'): the model resolution for a ``width x height`` image, ``size`` px high and the
    width keeping the aspect ratio, rounded to a multiple of 32 (the generator's stride), as
    :func:`prosplat.data.scene.resize_views` does."""
    if size < 32 or size % 32:
        raise ValueError(f"--size must be a positive multiple of 32, got {size}")
    return max(32, round(width * size / height / 32) * 32), size


def view_camera(view: PosedView, size: tuple[int, int] | None) -> Camera:
    """``view``'s camera after undistortion and resizing to ``size`` (W, H)."""
    cam = view.camera
    if view.distortion is not None and not view.distortion.is_identity:
        cam = undistorted_camera(cam, view.distortion)
    return cam if size is None else cam.resized(*size)


def load_views(
    posed: PosedSet,
    indices: Sequence[int],
    size: tuple[int, int] | None,
    background: Tensor,
    progress: bool = False,
) -> tuple[Tensor, list[Camera]]:
    """Images ``[N,3,H,W]`` (float32 in [0, 1]) and pinhole cameras of the chosen views:
    read, composited over ``background``, undistorted, and resized to ``size`` (W, H)
    (antialiased bilinear) with the intrinsics scaled to match; ``size`` None keeps the first
    view's size."""
    from tqdm import tqdm

    images, cameras = [], []
    it = tqdm(indices, desc="reading images", unit="image", disable=not progress)
    for i in it:
        view = posed.views[i]
        rgb, alpha = read_image_rgba(view.image)
        img = composite(rgb, alpha, background)
        cam = view.camera
        h, w = img.shape[-2:]
        if (w, h) != (cam.width, cam.height):
            # the file is the truth for the size (e.g. downscaled images beside full-size
            # cameras); normalised distortion coefficients do not depend on the size
            cam = cam.resized(w, h)
        if view.distortion is not None and not view.distortion.is_identity:
            # undistort at twice the model size (antialiased down first): as sharp after the
            # final resize, and a 1080p photo takes ~10 ms instead of ~0.8 s. The undistorted
            # camera scales with the image, so this commutes with view_camera.
            s = 1.0 if size is None else max(2 * size[0] / w, 2 * size[1] / h)
            if s < 1:
                w2, h2 = max(1, round(w * s)), max(1, round(h * s))
                img = F.interpolate(img[None], size=(h2, w2), mode="bilinear", antialias=True,
                                    align_corners=False)[0]  # fmt: skip
                cam = cam.resized(w2, h2)
            new = undistorted_camera(cam, view.distortion)
            img, cam = undistort_image(img, cam, view.distortion, new), new
        if size is None:
            size = (cam.width, cam.height)
        if (cam.width, cam.height) != size:
            img = F.interpolate(
                img[None], size=(size[1], size[0]), mode="bilinear", antialias=True,
                align_corners=False,
            )[0]  # fmt: skip
            cam = cam.resized(*size)
        images.append(img.clamp(0, 1))
        cameras.append(cam)
    return torch.stack(images), cameras


def near_far_from_points(
    points: Tensor, cameras: Sequence[Camera], observed: Sequence[Tensor] | None = None
) -> tuple[float, float] | None:
    """A depth range from sparse 3D points, or None when too few points are seen.

    For each camera, its points are those it observes (``observed[i]``, indices into
    ``points``) or, without tracks, every point in front of it that projects into its image.
    The depths of all of them together give ``near = NEAR_MARGIN · q02`` and ``far =
    FAR_MARGIN · q98`` (2nd and 98th percentiles: SfM outliers do not stretch the range).
    The rule is :func:`prosplat.poses.frame.near_far`, which the pose step writes its
    ``transforms.json`` near/far with: one rule for both.
    """
    w2c = np.stack([c.world_to_cam.double().numpy() for c in cameras])
    intrinsics = np.stack([c.K.double().numpy() for c in cameras])
    sizes = [(c.width, c.height) for c in cameras]
    tracks = None if observed is None else [o.long().numpy() for o in observed]
    return near_far(points.double().numpy(), w2c, tracks, sizes, intrinsics)
