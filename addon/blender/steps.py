"""Each user-visible step in two halves around a worker job: ``*_job`` reads Blender into a
task's plain params (main thread), ``apply_*`` turns the task's result into Blender data (main
thread, all or nothing). Operators run the job in between with a modal timer; :mod:`.api`
runs it synchronously. Nothing here blocks on torch.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import bpy

from ..core import depthsplat_file, photos
from . import cameras, pointcloud, runtime

NEAR_PROP, FAR_PROP = "prosplat_near", "prosplat_far"
TARGETS_PROP = "prosplat_targets"  # on an input collection: its collection of target cameras
SPLIT_PROP, KIND_PROP = "prosplat_split", "prosplat_target_kind"  # on imported cameras
VIEWS_PROP = "prosplat_views"  # on a Gaussian object: the input views it was made from
#: the point attribute with each Gaussian's input view (an index into VIEWS_PROP's names;
#: prosplat.core.ply.VIEW_PROPERTY), by which rendered views favour the input nearest them
VIEW_ATTR = "prosplat_view"
MADE_SIZE_PROP = "prosplat_made_size"  # on a Gaussian object: [w, h] the generator ran at
#: rendering this much above the size the Gaussians were made at shows gaps between splats
ABOVE_INPUT_TOLERANCE = 1.1


def resolve_dir(path: str, default_sub: str) -> Path:
    """An output folder: ``path`` (``//`` = beside the .blend; a plain relative path is
    relative to the working folder, as scripts expect) or, when empty,
    ``//prosplat_<default_sub>``.

    Raises:
        ValueError: the folder would be beside the .blend but the file was never saved: a
            silent fallback (the system temp folder) would hide the renders from the artist.
    """
    path = (path or "").strip() or f"//prosplat_{default_sub}"
    if path.startswith("//") and not bpy.data.filepath:
        raise ValueError(
            f"the .blend file is not saved, so '{path}' has no folder to be beside; save the "
            "file or choose an output folder"
        )
    return Path(bpy.path.abspath(path))


# ---- posed images -----------------------------------------------------------------------------
def inputs_name(path: str) -> str:
    """A collection name from the data's folder (a COLMAP model's project, not ``sparse/0``)."""
    folder = Path(bpy.path.abspath(path))
    folder = folder if folder.is_dir() else folder.parent
    while folder.name in ("0", "sparse") and folder.parent != folder:
        folder = folder.parent
    return f"ProSplat Inputs {folder.name}".strip()


def posed_images_job(path: str, images_dir: str | None = None) -> tuple[str, dict]:
    params = {"path": bpy.path.abspath(path)}
    if images_dir:
        params["images_dir"] = bpy.path.abspath(images_dir)
    return "read_posed_images", params


def free_names(names: list[str]) -> list[str]:
    """``names`` as they are when no object has them yet, else all with one suffix ``-2``,
    ``-3``... that frees every one (a re-import reads ``000-2``, ``001-2``, not a mix of
    ``000`` and ``001.001``)."""
    taken = set(bpy.data.objects.keys())
    k = 1
    while True:
        out = names if k == 1 else [f"{n}-{k}" for n in names]
        if not taken.intersection(out):
            return out
        k += 1


def apply_posed_images(result: dict, scene, name: str, set_resolution: bool = True):
    """A new collection with one camera per input image (each showing its image), named by
    the image's file stem. Frames marked ``"split": "target"`` (ProSplat's scene folders)
    become cameras to render in a second collection, ``TARGETS_PROP`` of the first.

    With ``set_resolution`` the scene renders at the first input's size and, when it has no
    camera, gets one: the first target, or a new camera at the first input's pose (never an
    input itself, which moving the view would move).

    Raises:
        ValueError: images missing on disk (named), or no input frame; nothing is created then.
    """
    frames = result.get("frames") or []
    if not frames:
        raise ValueError("the file holds no cameras")
    is_target = [f.get("split") == "target" for f in frames]
    inputs = [f for f, t in zip(frames, is_target, strict=True) if not t]
    if not inputs:
        raise ValueError(f"all {len(frames)} frames are marked 'target'; no input images")
    missing = [f["name"] for f in inputs if not f.get("image")]
    if missing:
        raise ValueError(
            f"{len(missing)} of {len(inputs)} images were not found ({', '.join(missing[:5])}"
            f"{', ...' if len(missing) > 5 else ''}); check the image folder"
        )
    names = free_names([f["name"] for f in frames])
    images_before = set(bpy.data.images.keys())
    coll = bpy.data.collections.new(name)
    made = [coll]
    try:
        if any(is_target):
            other = name.replace("Inputs", "Targets", 1) if "Inputs" in name else f"{name} Targets"
            made.append(bpy.data.collections.new(other))
        for f, cam_name, target in zip(frames, names, is_target, strict=True):
            obj = cameras.new_camera(cam_name, f["blender"], f.get("image"),
                                     made[1] if target else coll, result.get("far"))  # fmt: skip
            obj[SPLIT_PROP] = "target" if target else "input"
            if f.get("target_kind"):
                obj[KIND_PROP] = str(f["target_kind"])
        for key, prop in (("near", NEAR_PROP), ("far", FAR_PROP)):
            if result.get(key) is not None:
                coll[prop] = float(result[key])
        for c in made:
            scene.collection.children.link(c)
        if len(made) > 1:
            coll[TARGETS_PROP] = made[1]
    except BaseException:
        for c in made:
            remove_collection(c)
        for img in [i for i in bpy.data.images if i.name not in images_before and i.users == 0]:
            bpy.data.images.remove(img)  # loaded for the cameras just removed: no orphans
        raise
    if set_resolution:
        cameras.set_scene_resolution(scene, inputs[0]["blender"])
        if scene.camera is None:
            scene.camera = made[1].objects[0] if len(made) > 1 else cameras.new_camera(
                free_names(["ProSplat Camera"])[0], inputs[0]["blender"], None,
                scene.collection, result.get("far"))  # fmt: skip
    return coll


# ---- photos (no poses yet) --------------------------------------------------------------------
def photos_job(path: str, pose_dir: str | None = None, feature_size: int | None = None,
               max_frames: int | None = None) -> tuple[str, dict]:  # fmt: skip
    """The ``poses`` job for a folder of photos or a video (a chosen photo means its
    folder); the pose folder is ``pose_dir`` or :func:`..core.photos.default_pose_folder`."""
    source = photos.photo_source(bpy.path.abspath(path))
    out = Path(bpy.path.abspath(pose_dir)) if pose_dir else photos.default_pose_folder(source)
    if out.resolve() == source.resolve():
        raise ValueError(f"the pose folder {out} is the photos' own folder; choose another")
    params: dict[str, Any] = {"source": str(source), "out": str(out)}
    if feature_size:
        params["feature_size"] = int(feature_size)
    if max_frames:
        params["max_frames"] = int(max_frames)
    return "poses", params


def apply_photos(result: dict, scene, set_resolution: bool = True):
    """The cameras of a ``poses`` result, made exactly as Import Posed Images makes them, in
    a collection named for the folder (or video); returns (collection, one-line summary)."""
    name = photos.collection_name(Path(result["source"]))
    coll = apply_posed_images(result, scene, name, set_resolution)
    return coll, photos.describe(result, coll.name)


def targets_of(inputs):
    """The target-camera collection imported with ``inputs`` (None if it has none)."""
    return None if inputs is None else inputs.get(TARGETS_PROP)


def remove_collection(coll) -> None:
    """Delete a collection made here and everything in it (objects, their data)."""
    for obj in list(coll.all_objects):
        data = obj.data
        bpy.data.objects.remove(obj)
        if data is not None and data.users == 0:
            if isinstance(data, bpy.types.Camera):
                bpy.data.cameras.remove(data)
            elif isinstance(data, bpy.types.Mesh):
                bpy.data.meshes.remove(data)
    bpy.data.collections.remove(coll)


# ---- reconstruction ---------------------------------------------------------------------------
def background(scene) -> list[float]:
    """The colour RGBA input images are composited over (the scene's ProSplat setting; white,
    NeRF-synthetic's convention, where the add-on's settings are not registered)."""
    s = getattr(scene, "prosplat", None)
    return [float(x) for x in s.background] if s is not None else [1.0, 1.0, 1.0]


def view_choice(scene, mode: str | None = None) -> dict[str, Any]:
    """How reconstruction picks its views when more are checked than the generator takes:
    ``{"mode": "spread"}`` or ``{"mode": "nearest", "target": the active camera's dict}``."""
    s = getattr(scene, "prosplat", None)
    mode = (mode or (s.view_choice if s is not None else "SPREAD")).lower()
    if mode != "nearest":
        return {"mode": mode}
    if scene.camera is None:
        raise ValueError("'Nearest Active Camera' needs an active camera; set one or pick Spread")
    return {"mode": mode, "target": cameras.camera_dict(scene.camera, scene)}


def reconstruct_job(
    collection, scene, context=None, budget: int | None = None, refine_seconds: float | None = None
) -> tuple[str, dict]:
    """The reconstruct job on the input cameras whose *Use* box is checked; the worker picks
    at most the generator's ``max_views`` of them (``view_choice``)."""
    p = runtime.prefs(context)
    frames = cameras.input_frames(collection, scene, used_only=True)
    if len(frames) < 2:
        raise ValueError(
            f"'{collection.name}' has {len(frames)} checked camera(s); reconstruction needs at "
            "least 2 views (check more in the Inputs list)"
        )
    params: dict[str, Any] = {
        "frames": frames,
        "view_choice": view_choice(scene),
        "background": background(scene),
        "device": runtime.device_name(context),
        "weights": runtime.weights_path(context),
        "budget": int(p.budget if budget is None else budget) or None,
        "merge_flat": bool(getattr(p, "merge_flat", False)),
        "max_size": int(p.max_input_size) or None,
        "refine_seconds": float(
            getattr(p, "refine_seconds", 0.0) if refine_seconds is None else refine_seconds
        )
        or None,
    }
    for key, prop in (("near", NEAR_PROP), ("far", FAR_PROP)):
        if collection.get(prop) is not None:
            params[key] = float(collection[prop])
    return "reconstruct", params


def apply_gaussians(result: dict, name: str, collection, inputs=None):
    """The Gaussian object of a reconstruct or PLY import result (remembering, for a
    reconstruction, the views it was made from and the size the generator ran at)."""
    arrays = result.get("arrays")
    if not arrays or "position" not in arrays:
        raise ValueError("the worker returned no Gaussians")
    obj = pointcloud.create_object(name, arrays, collection)
    if inputs is not None:
        obj[pointcloud.INPUTS_PROP] = inputs.name
    if result.get("views"):
        obj[VIEWS_PROP] = [str(v) for v in result["views"]]
    if result.get("size"):
        obj[MADE_SIZE_PROP] = [int(v) for v in result["size"]]
    return obj


def describe_reconstruct(result: dict) -> str:
    """One line: Gaussians made (and by which DepthSplat, if one), views used and why, time,
    the depth range's source when the inputs' own points gave it (and how many views their
    depth was scaled in), and the leave-one-out warning when showing the nearest photo would
    beat the views."""
    st, secs = result.get("stats", {}), result.get("seconds", {})
    refined = f", refined {secs['refine']:.1f} s" if secs.get("refine") else ""
    why = f"; views: {result['view_reason']}" if result.get("view_reason") else ""
    by = depthsplat_file.describe_generator(result.get("generator"))
    warn = f"; {result['trust_warning']}" if result.get("trust_warning") else ""
    source = str(result.get("near_far_source", ""))
    depth = f"; depth range from {source}" if "points" in source else ""
    if depth and result.get("anchored_views"):
        depth += f", depth scaled to them in {result['anchored_views']} views"
    return (f"reconstructed {result['count']:,} Gaussians{by} ({st.get('input', 0):,} before "
            f"pruning{refined}) in {secs.get('total', 0):.1f} s{why}{depth}{warn}")  # fmt: skip


# ---- PLY --------------------------------------------------------------------------------------
def import_ply_job(path: str) -> tuple[str, dict]:
    return "import_ply", {"path": bpy.path.abspath(path)}


def export_ply_job(obj, path: str, overwrite: bool = False, apply_transform=True):
    params = {"path": bpy.path.abspath(path), "arrays": pointcloud.read_arrays(obj)}
    params["overwrite"] = bool(overwrite)
    if apply_transform:
        params["matrix_world"] = pointcloud.world_matrix(obj)
    return "export_ply", params


# ---- render view ------------------------------------------------------------------------------
def target_views(scene, mode: str, selected=(), active=None, inputs=None) -> list[dict[str, Any]]:
    """Target cameras for ``mode``: ``ACTIVE`` (scene camera), ``SELECTED`` (selected camera
    objects), ``FRAMES`` (the scene camera at every frame of the scene's range) or
    ``TARGETS`` (the target cameras imported with ``inputs``, each at its image's size)."""
    if mode == "TARGETS":
        coll = targets_of(inputs)
        objs = sorted((o for o in coll.all_objects if o.type == "CAMERA"), key=lambda o: o.name
                      ) if coll is not None else []  # fmt: skip
        if not objs:
            raise ValueError("the inputs have no target cameras; import a file with target "
                             "frames or pick another Render mode")  # fmt: skip
        return [{"name": o.name, "camera": cameras.input_frame(o, scene)["camera"]} for o in objs]
    if mode == "SELECTED":
        objs = sorted((o for o in selected if o.type == "CAMERA"), key=lambda o: o.name)
        if not objs:
            raise ValueError("no camera is selected; select one or more camera objects")
        return [{"name": o.name, "camera": cameras.camera_dict(o, scene)} for o in objs]
    cam = active or scene.camera
    if cam is None:
        raise ValueError("the scene has no active camera; set one (Ctrl+Numpad 0)")
    if mode == "ACTIVE":
        return [{"name": cam.name, "camera": cameras.camera_dict(cam, scene)}]
    if mode != "FRAMES":
        raise ValueError(f"unknown render mode {mode!r}")
    current = scene.frame_current
    views = []
    try:
        for frame in range(scene.frame_start, scene.frame_end + 1, max(1, scene.frame_step)):
            scene.frame_set(frame)
            views.append(
                {"name": f"{cam.name}_{frame:04d}", "camera": cameras.camera_dict(cam, scene),
                 "sequence": cam.name, "frame": frame}  # an image sequence NAME_####.png
            )  # fmt: skip
    finally:
        scene.frame_set(current)
    return views


def render_job(gaussians, targets, scene, output_dir: str, context=None, inputs=None,
               enhance=None, save_raw=False, save_depth=False) -> tuple[str, dict]:  # fmt: skip
    p = runtime.prefs(context)
    if inputs is None:
        inputs = bpy.data.collections.get(gaussians.get(pointcloud.INPUTS_PROP, ""))
    used = gaussians.get(VIEWS_PROP)
    frames = cameras.input_frames(inputs, scene, names=used) if inputs is not None else []
    arrays = pointcloud.read_arrays(gaussians)
    notes = []
    names = [f["name"] for f in frames]
    wanted = None if used is None else [str(n) for n in used]
    if names != wanted:
        # the Gaussians' view numbers index the cameras the reconstruction used, in its order:
        # with one of them gone or renamed they would favour the wrong input, so none is
        if arrays.pop(VIEW_ATTR, None) is not None and wanted is not None:
            gone = [n for n in wanted if n not in names]
            notes.append(
                f"input camera(s) {', '.join(gone[:3]) or 'of the reconstruction'} renamed or "
                "deleted since reconstructing: views blend every input alike instead of "
                "favouring the nearest (reconstruct again to restore it)"
            )
    out = resolve_dir(output_dir, "renders")
    params = {
        "notes": notes,
        "arrays": arrays,
        "matrix_world": pointcloud.world_matrix(gaussians),
        "targets": targets,
        "inputs": frames,
        "output_dir": str(out),
        "enhance": bool(p.enhance if enhance is None else enhance),
        "fill_holes": str(getattr(p, "fill_holes", runtime.Defaults.fill_holes)).lower(),
        "distill_steps": int(getattr(p, "distill_steps", 0)),
        "save_raw": bool(save_raw),
        "save_depth": bool(save_depth),
        "background": background(scene),
        "device": runtime.device_name(context),
        "weights": runtime.weights_path(context),
        "improve_weights": runtime.weights_path(context, "improve_weights_path"),
    }
    return "render", params


def resolution_warnings(gaussians, targets, inputs=None) -> list[str]:
    """A warning when a target renders above the size the Gaussians were made at (or, for
    Gaussians without that record, above the input images): pixel-aligned splats then leave
    gaps between them. Sizes compare by the long side, with a 10% tolerance."""
    made = gaussians.get(MADE_SIZE_PROP)
    what = "the Gaussians were made at"
    if not made and inputs is not None:
        sizes = [o.get(cameras.SIZE_PROP) for o in inputs.all_objects if o.type == "CAMERA"]
        sizes = [s for s in sizes if s]
        made = max(sizes, key=lambda s: max(s)) if sizes else None
        what = "the input images have"
    if not made:
        return []
    long_side = max(int(made[0]), int(made[1]))
    above = [t for t in targets
             if max(t["camera"]["width"], t["camera"]["height"]) > ABOVE_INPUT_TOLERANCE * long_side]  # fmt: skip
    if not above:
        return []
    t = above[0]
    size = f"{t['camera']['width']}x{t['camera']['height']}"
    more = f" (and {len(above) - 1} more)" if len(above) > 1 else ""
    return [f"rendering '{t['name']}'{more} at {size}, above the {made[0]}x{made[1]} {what}: "
            "expect holes between splats (lower the resolution or raise Input Size in the "
            "preferences and reconstruct again)"]  # fmt: skip


def apply_render(result: dict, show: bool = True) -> list:
    """Load each rendered view as a Blender Image (replacing an earlier one of the same name)
    and show the last one in any open Image Editor."""
    seq = result.get("sequence")
    if seq:  # a camera path: one image-sequence Image, not one Image per frame
        return [_show(_load_sequence(seq, len(result.get("views", []))), show)]
    images = []
    for view in result.get("views", []):
        name = f"ProSplat {view['name']}"
        img = bpy.data.images.get(name)
        if img is not None and img.source == "FILE":
            img.filepath = view["image"]
            img.reload()
        else:
            img = bpy.data.images.load(view["image"])
            img.name = name
        images.append(img)
    if images:
        _show(images[-1], show)
    return images


def _load_sequence(seq: dict, count: int):
    """The frames of a rendered camera path as one Image with source ``SEQUENCE``."""
    name = f"ProSplat {seq['prefix']}"
    old = bpy.data.images.get(name)
    if old is not None:
        bpy.data.images.remove(old)
    img = bpy.data.images.load(seq["first"])
    img.name, img.source = name, "SEQUENCE"
    img["prosplat_frames"] = [int(f) for f in seq["frames"]]
    return img


def _show(img, show: bool = True):
    """Show ``img`` in every open Image Editor (a sequence plays with the scene's frames:
    file number = scene frame, as the files are numbered by frame)."""
    if show and bpy.context.screen is not None:
        for area in bpy.context.screen.areas:
            if area.type == "IMAGE_EDITOR":
                area.spaces.active.image = img
                if img.source == "SEQUENCE":
                    frames = list(img.get("prosplat_frames", [1]))
                    user = area.spaces.active.image_user
                    user.frame_start, user.frame_offset = frames[0], frames[0] - 1
                    user.frame_duration = frames[-1] - frames[0] + 1
                    user.use_auto_refresh = True
    return img


def describe_render(result: dict) -> str:
    """One line for the status bar: views written, where, the median seconds per view, and
    each view's reference input."""
    views = result.get("views", [])
    refs = [f"{v['name']}<-{v['reference_name']}" for v in views if v.get("reference_name")]
    text = f"{len(views)} view(s) written to {result.get('output_dir', '?')}"
    if result.get("sequence"):
        text = (f"{len(views)} frame(s) written to {result.get('output_dir', '?')} as "
                f"{result['sequence']['pattern']}")  # fmt: skip
    kept = [f"{v.get('name', '?')}: {v['guard']}" for v in views if v.get("guard")]
    if result.get("seconds_per_view") is not None:
        text += f" ({result['seconds_per_view']:.2f} s per view)"
    text += f"; reference: {', '.join(refs[:6])}" if refs else ""
    if views and all(v.get("distilled") for v in views):
        text += "; rendered from the Gaussians distilled from every enhanced view"
    return text + (f"; raw render kept for {'; '.join(kept[:3])}" if kept else "")
