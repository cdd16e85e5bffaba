"""Each user-visible step in two halves around a worker job: ``*_job`` reads Blender into a
task's plain params (main thread), ``apply_*`` turns the task's result into Blender data (main
thread, all or nothing). Operators run the job in between with a modal timer; :mod:`.api`
runs it synchronously. Nothing here blocks on torch.
"""

from __future__ import annotations

import tempfile
from pathlib import Path
from typing import Any

import bpy

from . import cameras, pointcloud, runtime

NEAR_PROP, FAR_PROP = "prosplat_near", "prosplat_far"


def resolve_dir(path: str, default_sub: str) -> Path:
    """An output folder: ``path`` (``//`` = beside the .blend) or, when empty, ``default_sub``
    beside the saved .blend (the system temp folder for an unsaved file)."""
    path = (path or "").strip()
    if path.startswith("//") and not bpy.data.filepath:  # unsaved file: no folder to be beside
        return Path(tempfile.gettempdir()) / "prosplat" / path[2:]
    if path:
        return Path(bpy.path.abspath(path))
    base = Path(bpy.data.filepath).parent if bpy.data.filepath else Path(tempfile.gettempdir())
    return base / "prosplat" / default_sub


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


def apply_posed_images(result: dict, scene, name: str, set_resolution: bool = True):
    """A new collection with one camera per posed image (each showing its image).

    Raises:
        ValueError: images missing on disk (named); nothing is created then.
    """
    frames = result.get("frames") or []
    if not frames:
        raise ValueError("the file holds no cameras")
    missing = [f["name"] for f in frames if not f.get("image")]
    if missing:
        raise ValueError(
            f"{len(missing)} of {len(frames)} images were not found ({', '.join(missing[:5])}"
            f"{', ...' if len(missing) > 5 else ''}); check the image folder"
        )
    coll = bpy.data.collections.new(name)
    try:
        for f in frames:
            cameras.new_camera(f["name"], f["blender"], f["image"], coll, result.get("far"))
        for key, prop in (("near", NEAR_PROP), ("far", FAR_PROP)):
            if result.get(key) is not None:
                coll[prop] = float(result[key])
        scene.collection.children.link(coll)
    except BaseException:
        remove_collection(coll)
        raise
    if set_resolution:
        cameras.set_scene_resolution(scene, frames[0]["blender"])
        scene.camera = scene.camera or coll.objects[0]
    return coll


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
def reconstruct_job(
    collection, scene, context=None, budget: int | None = None, refine_seconds: float | None = None
) -> tuple[str, dict]:
    p = runtime.prefs(context)
    frames = cameras.input_frames(collection, scene)
    if len(frames) < 2:
        raise ValueError(
            f"'{collection.name}' has {len(frames)} camera; reconstruction needs at least 2 views"
        )
    params: dict[str, Any] = {
        "frames": frames,
        "device": runtime.device_name(context),
        "weights": runtime.weights_path(context),
        "budget": int(p.budget if budget is None else budget) or None,
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
    """The Gaussian object of a reconstruct or PLY import result."""
    arrays = result.get("arrays")
    if not arrays or "position" not in arrays:
        raise ValueError("the worker returned no Gaussians")
    obj = pointcloud.create_object(name, arrays, collection)
    if inputs is not None:
        obj[pointcloud.INPUTS_PROP] = inputs.name
    return obj


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
def target_views(scene, mode: str, selected=(), active=None) -> list[dict[str, Any]]:
    """Target cameras for ``mode``: ``ACTIVE`` (scene camera), ``SELECTED`` (selected camera
    objects) or ``FRAMES`` (the scene camera at every frame of the scene's range)."""
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
    frames = cameras.input_frames(inputs, scene) if inputs is not None else []
    out = resolve_dir(output_dir, "renders")
    params = {
        "arrays": pointcloud.read_arrays(gaussians),
        "matrix_world": pointcloud.world_matrix(gaussians),
        "targets": targets,
        "inputs": frames,
        "output_dir": str(out),
        "enhance": bool(p.enhance if enhance is None else enhance),
        "save_raw": bool(save_raw),
        "save_depth": bool(save_depth),
        "device": runtime.device_name(context),
        "weights": runtime.weights_path(context),
        "improve_weights": runtime.weights_path(context, "improve_weights_path"),
    }
    return "render", params


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
    """One line for the status bar: views written, where, and each view's reference input."""
    views = result.get("views", [])
    refs = [f"{v['name']}<-{v['reference_name']}" for v in views if v.get("reference_name")]
    text = f"{len(views)} view(s) written to {result.get('output_dir', '?')}"
    if result.get("sequence"):
        text = (f"{len(views)} frame(s) written to {result.get('output_dir', '?')} as "
                f"{result['sequence']['pattern']}")  # fmt: skip
    return text + (f"; reference: {', '.join(refs[:6])}" if refs else "")
